"""Fit of cell values outside the 18 dynamic parameters by finite differences: contact resistance, activation
energies, the lumped thermal model's heat capacities and heat transfer.

The compiled model gives exact sensitivities for the 18 dynamic parameters only; the fixed values of the cell
(``R_c``, ``E_D_s_n`` …, ``C1``, ``h2a`` …) act on the voltage and the temperature too and, for a real cell, are not
known. This fit moves them by bounded nonlinear least squares (scipy's trust-region reflective) on the log of
each value, with forward differences of whole simulations (``battlab.simulate``, thermal model on, each experiment
from its start SOC and surface temperature), on one target: the voltage [V] or the surface temperature [K]
against the logged ones. A group ``C1+C2`` is one factor on both values (their sum is what the data see).
A simulation that stops early (a voltage limit) holds its last error over the samples it did not reach.

Cost: (number of names + 1) simulations of every experiment per iteration, no sensitivities (a 1 h drive cycle at
1 s takes about 1-2 s); these values are constants of the compiled model, so every value tried compiles a new
one (about 25-30 s on a 2-core host): a few names and a few evaluations.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from battlab.cell import Cell
from protocols.errors import InputError
from protocols.profile import Profile

#: the targets a value fit can match
TARGETS = ("voltage", "temperature")
#: a value may move by at most this factor either way from its start
SPAN = 10.0


@dataclass(frozen=True)
class Trace:
    """One experiment with its logged voltage [V] and surface temperature [K] (NaN where not logged)."""

    name: str
    profile: Profile
    soc0: float
    ambient: float  # K
    T0: float | None  # K
    voltage: np.ndarray
    temperature: np.ndarray


@dataclass
class ValueFit:
    """The outcome: the cell with the fitted values, the values before and after, RMSE before and after per
    trace (mV or K), evaluations and wall time."""

    cell: Cell
    target: str
    names: tuple[str, ...]
    start: dict[str, float]
    values: dict[str, float]
    rmse_before: dict[str, float] = field(default_factory=dict)
    rmse_after: dict[str, float] = field(default_factory=dict)
    evaluations: int = 0
    seconds: float = 0.0
    message: str = ""

    def report(self) -> dict[str, object]:
        unit = "mV" if self.target == "voltage" else "K"
        return {
            "target": self.target,
            "names": list(self.names),
            "start": self.start,
            "values": self.values,
            f"rmse_before_{unit}": self.rmse_before,
            f"rmse_after_{unit}": self.rmse_after,
            "evaluations": self.evaluations,
            "seconds": self.seconds,
            "message": self.message,
        }


def parse_names(text: str, cell: Cell) -> tuple[str, ...]:
    """``"R_c,E_kappa,C1+C2"`` → groups; each member must be a positive number in the cell."""
    groups = tuple(g.strip() for g in text.split(",") if g.strip())
    if not groups:
        raise InputError(f"no value names in {text!r}")
    for g in groups:
        for k in g.split("+"):
            if k not in cell.values:
                raise InputError(f"value {k!r} (in {text!r}) is not a parameter of cell {cell.name!r}")
            v = cell.values[k]
            if not isinstance(v, int | float) or not v > 0:
                raise InputError(f"value {k!r} of cell {cell.name!r} is not a positive number; it cannot be fitted")
    if len(set(groups)) != len(groups):
        raise InputError(f"a value is named twice in {text!r}")
    return groups


def _apply(cell: Cell, groups: Sequence[str], factors: np.ndarray) -> Cell:
    return cell.with_values(
        **{k: float(cell[k]) * float(f) for g, f in zip(groups, factors, strict=True) for k in g.split("+")}
    )


def residuals(cell: Cell, traces: Sequence[Trace], target: str, stride: int = 1) -> list[np.ndarray]:
    """Simulated minus logged target of each trace (every ``stride``-th sample), [V] or [K]."""
    import battlab

    out = []
    for tr in traces:
        res = battlab.simulate(cell, tr.profile, soc0=tr.soc0, ambient=tr.ambient, T0=tr.T0, v_limits=(2.0, 4.5))
        sim = res.voltage if target == "voltage" else res.T_surface
        data = tr.voltage if target == "voltage" else tr.temperature
        n = sim.size
        err = np.empty(data.size)
        err[:n] = sim - data[:n]
        err[n:] = err[n - 1] if n else 1.0
        err = err[::stride]
        out.append(np.where(np.isfinite(err), err, 0.0))
    return out


def fit_values(
    cell: Cell, traces: Sequence[Trace], names: Sequence[str], *, target: str = "voltage", max_nfev: int = 20
) -> ValueFit:
    """Fit the values (or groups ``A+B``) ``names`` of ``cell`` to ``target`` of ``traces`` (see the module)."""
    if target not in TARGETS:
        raise InputError(f"value fit target {target!r}: expected one of {', '.join(TARGETS)}")
    if not traces:
        raise InputError("a value fit needs dynamic data")
    if target == "temperature" and not any(np.isfinite(tr.temperature).any() for tr in traces):
        raise InputError("a value fit to the temperature needs data that log the surface temperature")
    groups = tuple(names)
    scale = 1e3 if target == "voltage" else 1.0
    n_all = sum(tr.voltage.size for tr in traces)
    stride = max(1, n_all // 20000)  # at most about 20000 residuals (the FD Jacobian is dense)
    t0 = time.perf_counter()
    count = 0

    def fun(x: np.ndarray) -> np.ndarray:
        nonlocal count
        count += 1
        try:
            errs = residuals(_apply(cell, groups, np.exp(x)), traces, target, stride)
        except InputError:  # a value the model refuses: a large, finite cost
            return np.full(sum(-(-tr.voltage.size // stride) for tr in traces), 1.0)
        return scale * np.concatenate(errs)

    def rmse_of(c: Cell) -> dict[str, float]:
        errs = residuals(c, traces, target)
        return {tr.name: float(scale * np.sqrt(np.mean(e**2))) for tr, e in zip(traces, errs, strict=True)}

    before = rmse_of(cell)
    lim = np.log(SPAN)
    sol = least_squares(
        fun,
        np.zeros(len(groups)),
        bounds=(np.full(len(groups), -lim), np.full(len(groups), lim)),
        method="trf",
        diff_step=1e-2,
        x_scale=0.3,
        max_nfev=max_nfev,
    )
    fitted = _apply(cell, groups, np.exp(sol.x))
    keys = [k for g in groups for k in g.split("+")]
    return ValueFit(
        cell=fitted,
        target=target,
        names=groups,
        start={k: float(cell[k]) for k in keys},
        values={k: float(fitted[k]) for k in keys},
        rmse_before=before,
        rmse_after=rmse_of(fitted),
        evaluations=count,
        seconds=time.perf_counter() - t0,
        message=str(sol.message),
    )


def traces_of(dyn: Sequence[Any], cell: Cell, *, dt: float, soc0: float | None, ambient: Any) -> list[Any]:
    """The dynamic data as value-fit traces: the fit's experiments with the logged surface temperature [K] at
    their samples (NaN where not logged)."""
    from battlab.identify.data_files import ambient_of
    from battlab.identify.experiments import experiments_from_data, segments
    from battlab.io.data import SURFACE

    out = []
    for d in dyn:
        exps = experiments_from_data(d, cell, dt=dt, soc0=soc0, ambient=ambient_of(d, ambient))
        segs = segments(d)
        surf = d.temperature_K(SURFACE)
        for e, sl in zip(exps, segs if len(segs) == len(exps) else [None] * len(exps), strict=True):
            if surf is None or sl is None:
                temp = np.full(e.voltage.size, np.nan)
            else:
                temp = np.interp(d.t[sl.start] + e.profile.t, d.t[sl], surf[sl])
            out.append(Trace(e.name, e.profile, e.soc0, e.ambient, e.T0, e.voltage, temp))
    return out


def parse_value_stage(text: str) -> tuple[str, str]:
    """``[TARGET:]NAMES`` (TARGET voltage, the default, or temperature) as (target, names)."""
    target, _, names = text.rpartition(":")
    target = target.strip() or "voltage"
    if target not in TARGETS:
        raise InputError(f"--fit-values {text!r}: target {target!r} is not one of {', '.join(TARGETS)}")
    return target, names


def fit_value_stages(
    report: Any,
    dyn: Sequence[Any],
    value_stages: Sequence[tuple[str, str]],
    *,
    dt: float,
    soc0: float | None,
    ambient: Any,
    max_iter: int,
    on_values: Callable[[Any], None] | None,
) -> None:
    """Run the value fits on ``report.cell`` in order (each with about ``max_iter`` evaluations, an evaluation a
    simulation of every trace); the report's cell, summary and BPX metadata follow."""
    if not dyn:
        raise InputError("--fit-values needs dynamic data (tests other than the OCV test)")
    stages_ = [(target, parse_names(names, report.cell)) for target, names in value_stages]
    traces = traces_of(dyn, report.cell, dt=dt, soc0=soc0, ambient=ambient)
    done = report.summary.setdefault("value_fits", [])
    for target, names in stages_:
        vf = fit_values(report.cell, traces, names, target=target, max_nfev=max(1, max_iter // (len(names) + 1)))
        report.cell = vf.cell
        done.append(vf.report())
        for k, v in vf.values.items():
            report.summary["parameters"][k] = {"value": v, "ci95": [None, None], "at_bound": False}
        report.extra["value_fits"] = list(done)
        if on_values is not None:
            on_values(vf)
