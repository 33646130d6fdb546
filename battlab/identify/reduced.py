"""Fitting in the identifiable coordinates of the model's scaling symmetry (:mod:`battlab.identify.symmetry`).

When all four of R_s, D_s, k, R_f of an electrode are to be estimated, the data fix only τ = R_s²/D_s, κ = k/R_s
and ρ = R_f·R_s: every point of the orbit (λR_s, λ²D_s, λk, R_f/λ) gives the same voltage to round-off. Holding
R_s at the start cell's value and fitting D_s, k, R_f is therefore an exact reparametrisation (D_s, k, R_f are then
τ, κ, ρ in other units), with a regular information matrix where the 18-parameter one has an exact null
direction per electrode: the optimiser does not wander along the orbit, and the statistics need no
pseudo-inverse. After the fit the invariants get intervals (delta method, R_s a constant) and the four
parameters the set-identified intervals of the orbits consistent with them and the bounds
(:func:`symmetry.orbit_intervals`); the held R_s is reported as one point of its orbit, flagged set-identified.

A held R_s is only one representative: when D_s, k or R_f ends at a bound the orbit through a different R_s could
reach the invariants the bound denies (a true k at its lower bound is reachable only from R_s at or above the true
one). :func:`reseated` moves such an electrode along its orbit, which leaves the model's output unchanged, to where
the bound parameter has room, and the cumulative fit fits the stage again from there.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from battlab import parameters
from battlab.identify import symmetry
from battlab.identify.statistics import Estimate, Statistics


def split(names: Sequence[str]) -> tuple[list[str], list[str]]:
    """(the names to fit, the radii to hold): R_s of each electrode whose four orbit parameters are all in
    ``names``."""
    held = [f"R_s_{e}" for e in symmetry.complete_electrodes(names)]
    return [n for n in names if n not in held], held


def with_held(st: Statistics, held: Mapping[str, float]) -> Statistics:
    """The statistics of a fit with the radii ``held`` (name -> θ̄) fixed, completed: the invariants of each
    electrode with their intervals, set-identified intervals for R_s, D_s, k, R_f (R_s added as an estimate)."""
    if not held:
        return st
    names = [*st.names, *held]
    th = np.r_[np.asarray(st.theta_bar, float), [float(v) for v in held.values()]]
    p = len(st.names)
    base = st.covariance if st.covariance is not None else st.covariance_identifiable
    cov = np.zeros((len(names), len(names)))
    if base is not None:
        cov[:p, :p] = np.nan_to_num(np.asarray(base, float), nan=np.inf)
    invs = symmetry.invariants(names, th, cov, st.t_value)
    electrodes = symmetry.complete_electrodes(names)
    orbit = symmetry.orbit_intervals(invs, electrodes)
    est: list[Estimate] = []
    for e in st.estimates:
        if e.name in orbit:
            e = Estimate(e.name, e.value, e.theta_bar, None, None, orbit[e.name], None, e.at_bound, False, True)
        est.append(e)
    for n, t in held.items():
        spec = parameters.spec(n)
        est.append(Estimate(n, spec.denormalise(float(t)), float(t), None, None, orbit[n], None, None, False, True))
    bound = [e.name for e in est if e.at_bound and any(e.name in symmetry.ORBITS[x] for x in electrodes)]
    note = (
        ", ".join(held)
        + " held (the model's scaling symmetry: R_s, D_s, k, R_f of electrode(s) "
        + ", ".join(electrodes)
        + " fitted as the invariants "
        + ", ".join(f"{i.name} = {i.value:.4g} [{i.ci95[0]:.4g}, {i.ci95[1]:.4g}]" for i in invs.values())
        + "; the four have set-identified intervals)"
    )
    if bound:
        note += f"; {', '.join(bound)} at a bound: another R_s on the orbit might not be"
    reason = "; ".join(x for x in (st.reason, note) if x)
    return replace(st, estimates=tuple(est), invariants=tuple(invs.values()), reason=reason)


#: a move along the orbit smaller than this factor is not worth a refit
MIN_MOVE = 1.05


def orbit_room(values: Mapping[str, float], electrode: str) -> tuple[float, float]:
    """The factors λ (λ_lo ≤ 1 ≤ λ_hi) by which ``electrode``'s orbit can move, (R_s, D_s, k, R_f) → (λ R_s, λ² D_s,
    λ k, R_f / λ), with all four within their bounds (physical ``values``)."""
    lo, hi = 0.0, float("inf")
    for name, e in symmetry.ORBITS[electrode].items():
        spec = parameters.spec(name)
        a, b = (spec.lower / values[name]) ** (1 / e), (spec.upper / values[name]) ** (1 / e)
        a, b = min(a, b), max(a, b)
        lo, hi = max(lo, a), min(hi, b)
    return min(lo, 1.0), max(hi, 1.0)


def reseated(cell: Any, held: Sequence[str], at_bound: Mapping[str, str | None]) -> tuple[Any, dict[str, float]] | None:
    """``cell`` moved along the orbit of each held electrode whose D_s, k or R_f sits at a bound (``at_bound``: name
    → ``"lower"``/``"upper"``, the fit's :class:`~battlab.identify.statistics.Estimate` verdicts), halfway (in log λ)
    to the farthest point in the direction that frees it where all four stay within their bounds; the moves {R_s: λ}.
    None when no electrode can move by :data:`MIN_MOVE` (nothing at a bound, bounds pulling both ways, no room)."""
    moves: dict[str, float] = {}
    values: dict[str, float] = {}
    for r in held:
        electrode = r.rsplit("_", 1)[1]
        orbit = symmetry.ORBITS[electrode]
        vals = {n: float(cell[n]) for n in orbit}
        # at its upper bound λ^e must fall, at its lower bound rise
        want = {
            (-1 if at_bound[n] == "upper" else 1) * (1 if e > 0 else -1) for n, e in orbit.items() if at_bound.get(n)
        }
        if len(want) != 1:
            continue
        lo, hi = orbit_room(vals, electrode)
        lam = hi**0.5 if want == {1} else lo**0.5
        if max(lam, 1 / lam) < MIN_MOVE:
            continue
        moves[r] = lam
        values.update({n: v * lam ** orbit[n] for n, v in vals.items()})
    return (cell.with_values(**values), moves) if moves else None


def held_values(cell: Any, held: Sequence[str]) -> dict[str, float]:
    """θ̄ of the held radii in ``cell``."""
    return {n: float(cell.normalised(n)) for n in held}


__all__ = ["held_values", "orbit_room", "reseated", "split", "with_held"]
