"""Run logs of the campaign → fit and validation experiments, capacities and repeated-trial voltages."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from battlab.cell import Cell
from battlab.identify.experiments import Experiment
from battlab.io.checks import DataWarning
from battlab.io.data import LoggedData, load_data
from battlab.noise import NoiseModel
from protocols.errors import InputError

STEP_INDEX = "Step Index / 1"


def load(path: str | Path) -> LoggedData:
    """A run log. The engine logs the last sample of a step and the first of the next at the same instant when the
    current does not change between them; the reader keeps the later one and warns, which is expected here."""
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*repeated time stamp", category=DataWarning)
        return load_data(path)


def steps(data: LoggedData, first: int, last: int | None = None) -> np.ndarray:
    """Rows of plan steps ``first``..``last`` (1-based step indices, inclusive)."""
    si = data.columns[STEP_INDEX]
    return (si >= first) & (si <= (last if last is not None else np.inf))


def discharged_ah(path: str | Path, step: int) -> float:
    """Charge [Ah] discharged in plan step ``step`` of a log (the capacity check's discharge)."""
    d = load(path)
    m = steps(d, step, step)
    if m.sum() < 2:
        raise InputError(f"{path}: step {step} has no samples (did the run finish?)")
    t, i = d.t[m], d.current[m]
    return float(-np.sum(i[:-1] * np.diff(t)) / 3600.0)


def experiment(
    path: str | Path, cell: Cell, *, name: str, noise: NoiseModel | None = None, dt: float = 1.0
) -> Experiment:
    """One experiment from a measurement log (it starts at rest: the start SOC comes from the rest voltage on
    ``cell``'s OCV), resampled every ``dt`` s, weighted by ``noise``."""
    from battlab.identify.experiments import experiments_from_data

    d = load(path)
    exps = experiments_from_data(d, cell, dt=dt, noise=noise)
    if len(exps) != 1:
        raise InputError(f"{path}: expected one uninterrupted measurement, found {len(exps)} segments")
    return replace(exps[0], name=name)


def experiment_after_preparation(
    prep: str | Path, path: str | Path, cell: Cell, *, name: str, noise: NoiseModel | None = None, dt: float = 1.0
) -> Experiment:
    """:func:`experiment` with its preparation as an unscored lead-in (:func:`battlab.identify.runlog.with_lead_in`):
    from the end of the preparation's full charge (plan step 2, the rest after it) through the adjustment to the
    profile's start SOC and the rest, so that the gradients the adjustment leaves in the particles are simulated
    instead of taken as a uniform cell at rest (on nca18650-true, τ⁻ ≈ 4.3 h: after the 30 min rest a 0.2-SOC
    adjustment at C/2 leaves s² 27 on the 30-min pulse profile 48, 541 after a 0.6-SOC one). Its start SOC is the
    measurement's rest-voltage SOC minus the charge passed since the full charge (the rest voltage is itself still
    relaxing: a fit frees it per experiment, ``soc_span``)."""
    from battlab.identify.runlog import with_lead_in

    e = experiment(path, cell, name=name, noise=noise, dt=dt)
    d = load(prep)
    step2 = d.columns[STEP_INDEX] == 2
    first = np.flatnonzero(step2)
    if first.size == 0 or len(d) < 3 or np.max(np.abs(d.current[step2])) > 0.01 * float(cell["Q_nom"]):
        raise InputError(f"{prep}: no rest after a full charge (plan step 2) to start the lead-in from")
    a, b = int(first[0]), len(d) - 1
    passed = float(np.sum(d.current[a:b] * np.diff(d.t[a : b + 1]))) / 3600.0
    return with_lead_in(e, d, a, b, float(np.clip(e.soc0 - passed / cell.capacity(), 0.0, 1.0)))


def with_truth(e: Experiment, truth: Cell, rest_voltage: float) -> Experiment:
    """``e`` with the noise-free voltage of the true cell under the logged current, started from the true cell's
    SOC at the logged rest voltage (the virtual lab's reference for RMSE)."""
    from battlab.identify.forward import ForwardModel
    from battlab.identify.validation import prediction

    lo, hi = float(truth.ocv(0.0)), float(truth.ocv(1.0))
    soc = truth.soc_from_voltage(float(np.clip(rest_voltage, lo, hi)))
    fm = ForwardModel(truth, v_margin=0.15)
    v, _ = prediction(fm, truth, replace(e, soc0=soc))
    v = np.where(np.isfinite(v), v, e.voltage)
    return replace(e, truth=v)


def rest_voltage(path: str | Path) -> float:
    """The first logged voltage (the measurement starts at rest)."""
    return float(load(path).voltage[0])


def trial_voltages(paths: Sequence[str | Path], step: int = 2) -> np.ndarray:
    """Voltages of repeated trials of one profile step, shape (n_trials, n_samples) (cut to the shortest)."""
    vs = []
    for p in paths:
        d = load(p)
        vs.append(d.voltage[steps(d, step, step)])
    n = min(v.size for v in vs)
    if n < 10:
        raise InputError(f"repeated trials {', '.join(map(str, paths))}: fewer than 10 samples in the profile step")
    return np.stack([v[:n] for v in vs])


def net_ah(path: str | Path, step: int = 2) -> float:
    """Net charge [Ah] (positive = charged) passed in a step of a log."""
    d = load(path)
    m = steps(d, step, step)
    return float(np.sum(d.current[m][:-1] * np.diff(d.t[m])) / 3600.0)
