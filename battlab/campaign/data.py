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
    """:func:`experiment` with its preparation's log ``prep`` as an unscored lead-in
    (:func:`battlab.identify.runlog.after_preparation`)."""
    from battlab.identify.runlog import after_preparation

    return after_preparation(experiment(path, cell, name=name, noise=noise, dt=dt), load(prep), cell)


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
