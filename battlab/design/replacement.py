"""Replacements for designed profiles that cannot be run: for every selected profile, the other candidates ranked by
how well each takes its place in the designs that selected it.

A design is screened on the cell known before the experiments (the equilibrium cell with its start dynamics), so a
profile can still hit a safety limit on the cell it meets: on the virtual lab four of nine designed profiles (pulses
of 6–12 A from SOC 0.2) passed 2.45 V although the design cell stayed above 2.7 V. Such a profile is replaced by
its best swap instead of being lost: for a design (criterion φ, selection S, information F_i restricted to its
parameters, on the identifiable subspace when the group is singular, as in :func:`battlab.design.groups.design_stage`)
candidate c scores the efficiency of (S without the lost profile, plus c) against S; a profile selected by several
designs scores the mean of its designs' efficiencies. Candidates are the window-screened ones that no design
selected.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from battlab.design import criteria
from battlab.design.criteria import Criterion
from battlab.design.groups import GroupDesign, identifiable_basis, null_directions
from battlab.design.information import Information

#: replacements listed per selected profile
DEPTH = 8


def replacements(
    info: Information, designs: Sequence[GroupDesign], criterion: Criterion | str, depth: int = DEPTH
) -> dict[Any, list[Any]]:
    """{selected profile id: up to ``depth`` candidate ids, best replacement first} (see the module docstring)."""
    c = Criterion.of(criterion)
    selected = {pid for d in designs for pid in d.selected}
    pos = {pid: k for k, pid in enumerate(info.ids)}
    cand = np.array([k for k, pid in enumerate(info.ids) if pid not in selected], int)
    if cand.size == 0:
        return {pid: [] for pid in selected}
    F_all = info.F
    scores: dict[Any, list[np.ndarray]] = {pid: [] for pid in selected}
    for d in designs:
        idx = [info.index(n) for n in d.parameters]
        Fi = F_all[:, idx][:, :, idx]
        if null_directions(Fi.sum(axis=0), d.parameters):  # as the design did: on the identifiable subspace
            B = identifiable_basis(Fi.sum(axis=0))
            Fi = np.einsum("pa,lpq,qb->lab", B, Fi, B)
        sel = [pos[pid] for pid in d.selected if pid in pos]
        F_sel = Fi[sel].sum(axis=0)
        for pid in d.selected:
            if pid not in pos:
                continue
            rest = F_sel - Fi[pos[pid]]
            scores[pid].append(_efficiencies(rest[None] + Fi[cand], F_sel, c))
    out: dict[Any, list[Any]] = {}
    for pid, s in scores.items():
        if not s:
            out[pid] = []
            continue
        mean = np.mean(np.vstack(s), axis=0)
        order = np.argsort(-np.nan_to_num(mean, nan=-np.inf), kind="stable")[:depth]
        out[pid] = [info.ids[cand[k]] for k in order if np.isfinite(mean[k]) and mean[k] > 0]
    return out


def _efficiencies(Fs: np.ndarray, F_ref: np.ndarray, c: Criterion) -> np.ndarray:
    """Efficiency of each matrix in ``Fs`` against ``F_ref`` (see :func:`battlab.design.criteria.efficiency`)."""
    if c is Criterion.D:
        p = F_ref.shape[0]
        return np.exp((criteria.values(Fs, c) - criteria.logdet(F_ref)) / p)
    return np.array([criteria.efficiency(F, F_ref, c) for F in Fs])


def as_json(table: Mapping[Any, Sequence[Any]]) -> dict[str, list[Any]]:
    """The table with string keys (JSON objects)."""
    return {str(k): list(v) for k, v in table.items()}


@dataclass
class Guard:
    """What aborted runs teach about the design cell: a run that hit a safety limit although the design cell kept
    ``margin`` volts inside it shows that the cell met is at least that much further out, so a profile whose
    design-cell margin on that side is no larger is predicted to abort too and is not run. ``lower``/``upper``:
    the plan's abort limits [V]."""

    lower: float
    upper: float
    need_low: float = -np.inf  # [V] margins above the lower limit that aborted (the largest so far)
    need_high: float = -np.inf

    def admits(self, v_min: float, v_max: float) -> str | None:
        """None when a profile whose design-cell voltage spans [v_min, v_max] may run, else why not."""
        if v_min - self.lower <= self.need_low:
            return f"its design-cell minimum {v_min:.3f} V is no further above {self.lower:g} V than a run that aborted"
        if self.upper - v_max <= self.need_high:
            return f"its design-cell maximum {v_max:.3f} V is no further below {self.upper:g} V than a run that aborted"
        return None

    def learn(self, v_min: float, v_max: float, low_side: bool) -> None:
        """A profile with that design-cell span aborted at the lower (``low_side``) or upper limit."""
        if low_side:
            self.need_low = max(self.need_low, v_min - self.lower)
        else:
            self.need_high = max(self.need_high, self.upper - v_max)


@dataclass(frozen=True)
class Attempt:
    """One designed slot's runs: the profile designed, the one whose data fill it (None: lost), and what happened
    to each profile tried or passed over (id → "completed", the abort reason, or why it was not run)."""

    designed: Any
    used: Any | None
    tried: dict[Any, str]


def run_designed(
    ids: Sequence[Any],
    spares: Mapping[Any, Sequence[Any]],
    span: Callable[[Any], tuple[float, float]],
    run: Callable[[Any], tuple[bool, str, float]],
    guard: Guard,
    max_runs: int = 3,
) -> list[Attempt]:
    """Run the designed profiles ``ids`` in order, each replaced, when it aborts or is predicted to, by its first
    spare (``spares[id]``, best first) that ``guard`` admits and no other slot used, up to ``max_runs`` runs per slot.

    ``span(id)``: the profile's design-cell voltage range [V]; ``run(id)``: runs it and returns (completed, reason,
    the last logged voltage [V], which tells the side of an abort)."""
    used: set[Any] = set(ids)
    out = []
    for pid in ids:
        tried: dict[Any, str] = {}
        chosen = None
        runs = 0
        for cand in [pid, *(s for s in spares.get(pid, ()) if s not in used)]:
            if runs >= max_runs:
                break
            lo, hi = span(cand)
            why = guard.admits(lo, hi)
            if why is not None:
                tried[cand] = f"not run: {why}"
                continue
            used.add(cand)
            runs += 1
            ok, reason, v_last = run(cand)
            tried[cand] = "completed" if ok else reason
            if ok:
                chosen = cand
                break
            guard.learn(lo, hi, v_last < 0.5 * (guard.lower + guard.upper))
        out.append(Attempt(pid, chosen, tried))
    return out


def voltage_spans(store: Any, ids: Sequence[Any]) -> dict[Any, tuple[float, float]]:
    """Each profile's simulated voltage range on the design cell [V] (the sweep's voltage)."""
    from battlab.design.sweep.store import GROUP, group_name

    out = {}
    for pid in ids:
        v = store.f[GROUP][group_name(pid)]["voltage"][()]
        out[pid] = (float(np.min(v)), float(np.max(v)))
    return out


#: [V] a profile whose screen-cell voltage comes this close to an abort limit is predicted to abort
SCREEN_MARGIN_V = 0.05


def simulated_span(cell: Any, profile: Any, ambient_K: float, limits: tuple[float, float]) -> tuple[float, float]:
    """The voltage range [V] of ``profile`` from its start SOC on ``cell`` (e.g. the equilibrium cell with the slow
    cycle's diffusivities); a run that stops at a limit 0.5 V beyond ``limits`` spans past it (±inf)."""
    from battlab.simulation import simulate

    lo, hi = limits
    res = simulate(cell, profile, soc0=float(profile.soc0), ambient=ambient_K, v_limits=(lo - 0.5, hi + 0.5))
    v = np.asarray(res.voltage, float)
    vmin = float(np.min(v)) if v.size else -np.inf
    vmax = float(np.max(v)) if v.size else np.inf
    if res.ended_by is not None:
        low = v.size == 0 or abs(vmin - (lo - 0.5)) < abs(vmax - (hi + 0.5)) or "V <" in str(res.ended_by)
        vmin, vmax = (-np.inf, vmax) if low else (vmin, np.inf)
    return vmin, vmax
