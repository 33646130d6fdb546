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
reach the invariants the bound denies; the note says so.
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


def held_values(cell: Any, held: Sequence[str]) -> dict[str, float]:
    """θ̄ of the held radii in ``cell``."""
    return {n: float(cell.normalised(n)) for n in held}


__all__ = ["held_values", "split", "with_held"]
