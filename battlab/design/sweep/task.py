"""The per-profile task of the sweep (runs in a worker process or on a Dask worker): simulate one profile with
all 18 sensitivities, screen it, and reduce the 1 s rows to the triangular factor R (SᵀS = RᵀR)."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from battlab.cell import Cell
from battlab.design.screening import constraint_flags, is_solver_failure
from battlab.design.sweep.keys import SweepConfig, id_value
from protocols.profile import Profile

# --- the per-profile task (runs in a worker) ---------------------------------------------------------------


@dataclass
class Task:
    """One simulation: the profile's samples, the cell as its TOML dict, the settings (all picklable: profiles
    and cells hold mapping proxies, which do not pickle).

    ``extend_rest_s`` > 0 (conventional tests): run until a limit stops the profile, then cut it there and
    append this much rest [s] (the relaxation is part of the measurement).
    """

    key: str
    pid: int | str
    t: np.ndarray
    current: np.ndarray
    soc0: float | None
    cell_dict: dict[str, Any]
    config: SweepConfig
    extend_rest_s: float = 0.0

    @classmethod
    def of(cls, key: str, p: Profile, cell_dict: dict[str, Any], config: SweepConfig, rest: float = 0.0) -> Task:
        return cls(key, id_value(p.id), p.t, p.current, p.soc0, cell_dict, config, rest)

    @property
    def profile(self) -> Profile:
        return Profile(self.t, self.current, id=self.pid, soc0=self.soc0)

    @property
    def duration(self) -> float:
        return float(self.t[-1] - self.t[0])


@dataclass
class Outcome:
    """What a worker returns for one profile. status: "ok", "flagged" (screen) or "failed" (with reason)."""

    id: int | str
    key: str
    status: str
    reason: str | None = None
    flags: list[str] = field(default_factory=list)
    ended_by: str | None = None
    t: np.ndarray | None = None
    current: np.ndarray | None = None
    voltage: np.ndarray | None = None
    T_surface: np.ndarray | None = None
    sens_V: np.ndarray | None = None
    sens_T: np.ndarray | None = None
    index_1s: np.ndarray | None = None
    R: np.ndarray | None = None
    seconds: float = 0.0


_CELLS: dict[str, Cell] = {}


def _cell_from(d: dict[str, Any]) -> Cell:
    blob = json.dumps(d, sort_keys=True, default=str)
    if blob not in _CELLS:
        _CELLS[blob] = Cell._from_toml_dict(d, str(d.get("name", "cell")))
    return _CELLS[blob]


def one_second_rows(t: np.ndarray, tol: float = 1e-6) -> np.ndarray:
    """Indices of the samples at whole seconds from the start (the Fisher information's 1 s sampling)."""
    rel = np.asarray(t, float) - float(t[0])
    return np.flatnonzero(np.abs(rel - np.round(rel)) <= tol).astype(np.int64)


def resample_1s(t: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(t, y) at whole seconds from the start: selected when every second is a sample, else interpolated."""
    t = np.asarray(t, float)
    grid = t[0] + np.arange(int(np.floor(t[-1] - t[0] + 1e-9)) + 1)
    rows = one_second_rows(t)
    if rows.size == grid.size:
        return t[rows], np.asarray(y)[rows]
    y2 = np.asarray(y, float).reshape(t.size, -1)
    out = np.column_stack([np.interp(grid, t, y2[:, j]) for j in range(y2.shape[1])])
    return grid, out.reshape((grid.size, *np.asarray(y).shape[1:]))


def triangular_factor(S: np.ndarray) -> np.ndarray:
    """R (p × p, upper triangular) with Rᵀ R = Sᵀ S, from a Householder QR of S (n × p)."""
    S = np.asarray(S, float)
    p = S.shape[1]
    if S.shape[0] < p:
        S = np.vstack([S, np.zeros((p - S.shape[0], p))])
    return np.linalg.qr(S, mode="r")


def run_task(task: Task) -> Outcome:
    """Simulate one profile with sensitivities and screen it (pure: safe in any worker process)."""
    from battlab.simulation import simulate

    t0 = time.perf_counter()
    prof = task.profile
    pid = task.pid
    try:
        cell = _cell_from(task.cell_dict)
        cfg = task.config
        window = cfg.limits.window(cell)
        kw = dict(ambient=cfg.ambient, isothermal=cfg.isothermal, mesh=cfg.mesh, v_limits=window)
        if task.extend_rest_s > 0:
            prof = _cut_and_rest(cell, prof, task.extend_rest_s, kw)
        res = simulate(cell, prof, sensitivities=list(cfg.names), **kw)
    except Exception as exc:  # recorded with the reason, never dropped
        return Outcome(pid, task.key, "failed", f"{type(exc).__name__}: {exc}", seconds=time.perf_counter() - t0)
    out = Outcome(pid, task.key, "ok", ended_by=res.ended_by, seconds=0.0)
    out.t, out.current = res.t, res.current
    out.voltage, out.T_surface = res.voltage, res.T_surface
    out.sens_V, out.sens_T = res.sensitivities, res.sensitivities_T
    usable = res.t.size >= 2 and res.sensitivities is not None and bool(np.all(np.isfinite(res.sensitivities)))
    if is_solver_failure(res.ended_by):
        out.status, out.reason = "failed", res.ended_by
        return _timed(out, t0)
    out.flags = constraint_flags(res, cfg.limits, window)
    if out.flags:
        out.status, out.reason = "flagged", "; ".join(out.flags)
    elif not usable:
        out.status, out.reason = "failed", "no finite sensitivities"
    if usable:
        out.index_1s = one_second_rows(res.t)
        out.R = triangular_factor(res.sensitivities[out.index_1s])
    return _timed(out, t0)


def _timed(out: Outcome, t0: float) -> Outcome:
    out.seconds = time.perf_counter() - t0
    return out


def _cut_and_rest(cell: Cell, prof: Profile, rest_s: float, kw: dict[str, Any]) -> Profile:
    """The profile up to where a limit stops it (whole seconds), followed by ``rest_s`` of rest."""
    from battlab.simulation import simulate

    probe = simulate(cell, prof, **kw)
    if is_solver_failure(probe.ended_by):
        raise RuntimeError(f"probe run failed: {probe.ended_by}")
    t_end = float(np.floor(probe.t[-1] - prof.t[0])) if probe.ended_by else prof.duration
    if t_end < 1.0:
        raise RuntimeError(f"{probe.ended_by} at the start")
    keep = prof.t - prof.t[0] < t_end - 1e-9
    t = np.concatenate([prof.t[keep] - prof.t[0], [t_end], t_end + np.arange(1.0, rest_s + 0.5)])
    i = np.concatenate([prof.current[keep], np.zeros(t.size - int(keep.sum()))])
    return Profile(t, i, id=prof.id, kind=prof.kind, soc0=prof.soc0, params=dict(prof.params))
