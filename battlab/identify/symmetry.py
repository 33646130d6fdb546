"""The model's exact scaling symmetry, and set-identified intervals for the parameters it moves.

For each electrode the DFN–thermal model (Appendix A) is unchanged, for every current, by

    (R_s, D_s, k, R_f) → (λ R_s, λ² D_s, λ k, R_f / λ),   λ > 0:

the particle equation in ξ = r/R_s (A1–A2) depends on D_s/R_s² and on the surface flux through (D_s/R_s)·∂c/∂ξ;
with a_s = 3ε_s/R_s a fixed volumetric current a_s F j (A15) needs a flux per area j ∝ R_s, so ∂c/∂ξ is unchanged;
Butler–Volmer (A17) depends on j/i₀ with i₀ ∝ k (A18), and the film drop (A19) on j·R_f; the heat sources (B1–B5)
see only i_e, η and j·a_s. Voltage and temperature agree to 5e-14 V and 6e-14 K at λ = 0.7 and 1.5
(``tests/battlab/identify/test_identify_symmetry.py``). No experiment can therefore separate the four values of
an electrode: only the three invariants

    τ = R_s²/D_s [s]  (diffusion time),   κ = k/R_s,   ρ = R_f·R_s

are identifiable, and the information matrix of all 18 parameters has one exact null direction per electrode
(the paper's claim that all 18 are identifiable does not hold for this model).

What the data do say about each of the four is an interval: the values on the symmetry orbits whose invariants
lie in their 95 % intervals and whose four parameters all lie within their bounds (a set-identified interval,
projected conservatively, :func:`orbit_intervals`). The bounds make it finite and often informative.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from battlab import parameters

#: Exponent of λ for each parameter of an electrode's symmetry orbit.
ORBITS: dict[str, dict[str, int]] = {e: {f"R_s_{e}": 1, f"D_s_{e}": 2, f"k_{e}": 1, f"R_f_{e}": -1} for e in ("n", "p")}

#: Identifiable invariants per electrode: name → {parameter: exponent} (products of powers).
INVARIANTS: dict[str, dict[str, dict[str, int]]] = {
    e: {
        f"tau_{e}": {f"R_s_{e}": 2, f"D_s_{e}": -1},  # R_s²/D_s [s]
        f"kappa_{e}": {f"k_{e}": 1, f"R_s_{e}": -1},  # k/R_s
        f"rho_{e}": {f"R_f_{e}": 1, f"R_s_{e}": 1},  # R_f·R_s [Ω m³]
    }
    for e in ("n", "p")
}


@dataclass(frozen=True)
class Invariant:
    """An identifiable combination: value and 95 % interval (physical units)."""

    name: str
    value: float
    ci95: tuple[float, float]
    definition: str


def complete_electrodes(names: Sequence[str]) -> list[str]:
    """Electrodes whose four orbit parameters are all fitted (their symmetry is then unresolved)."""
    return [e for e, orbit in ORBITS.items() if all(n in names for n in orbit)]


def invariants(
    names: Sequence[str], theta_bar: np.ndarray, covariance: np.ndarray, t_value: float
) -> dict[str, Invariant]:
    """The invariants of each complete electrode with their 95 % intervals (delta method in log space).

    ``covariance`` (p, p) in θ̄ must be valid for estimable functions (e.g. the pseudo-inverse of JᵀWJ); the
    invariants are estimable because their gradients are orthogonal to the orbit. Each interval is intersected
    with the range the identification bounds allow (:func:`bounds_range`): a parameter the data barely move (a
    rate constant at its bound, σ̄ of order 10²) gives a log-space half-width of hundreds, whose ends are beyond
    floating point and say no more than the bounds do.
    """
    names = list(names)
    out: dict[str, Invariant] = {}
    for e in complete_electrodes(names):
        for inv, powers in INVARIANTS[e].items():
            g = np.zeros(len(names))
            log_v = 0.0
            for n, a in powers.items():
                k = names.index(n)
                spec = parameters.spec(n)
                v = spec.denormalise(float(theta_bar[k]))
                log_v += a * math.log(v)
                g[k] = a * spec.dvalue_dnormalised(v) / v  # d log(inv) / d θ̄
            var = float(g @ covariance @ g)
            half = t_value * math.sqrt(var) if np.isfinite(var) and var >= 0 else math.inf
            log_lo, log_hi = (math.log(b) for b in bounds_range(powers))
            # within the bounds' range, and never excluding the estimate itself (a start outside the bounds)
            lo = math.exp(min(log_v, max(log_v - half, log_lo)))
            hi = math.exp(max(log_v, min(log_v + half, log_hi)))
            definition = " · ".join(f"{n}^{a}" if a != 1 else n for n, a in powers.items())
            out[inv] = Invariant(inv, math.exp(log_v), (lo, hi), definition)
    return out


def bounds_range(powers: dict[str, int]) -> tuple[float, float]:
    """The range of a product of powers ∏ θ_n^a when every θ_n lies within its identification bounds."""
    lo = hi = 1.0
    for n, a in powers.items():
        spec = parameters.spec(n)
        small, large = (spec.lower, spec.upper) if a > 0 else (spec.upper, spec.lower)
        lo *= small**a
        hi *= large**a
    return lo, hi


def orbit_intervals(invs: dict[str, Invariant], electrodes: Sequence[str]) -> dict[str, tuple[float, float]]:
    """Set-identified 95 % intervals of R_s, D_s, k, R_f of each electrode: every value reachable on a symmetry
    orbit with the invariants within their intervals and all four parameters within their bounds (an outer
    bound of that set's projection)."""
    out: dict[str, tuple[float, float]] = {}
    for e in electrodes:
        b = {n: (parameters.spec(n).lower, parameters.spec(n).upper) for n in ORBITS[e]}
        tau, kap, rho = (invs[f"{x}_{e}"].ci95 for x in ("tau", "kappa", "rho"))
        rs, ds, k, rf = (f"R_s_{e}", f"D_s_{e}", f"k_{e}", f"R_f_{e}")
        with np.errstate(divide="ignore", invalid="ignore"):
            r_lo = max(b[rs][0], math.sqrt(tau[0] * b[ds][0]), _div(b[k][0], kap[1]), _div(rho[0], b[rf][1]))
            r_hi = min(b[rs][1], math.sqrt(tau[1] * b[ds][1]), _div(b[k][1], kap[0]), _div(rho[1], b[rf][0]))
        if not r_lo <= r_hi:  # numerically empty (the estimate itself lies on a feasible orbit): keep the bounds
            r_lo, r_hi = b[rs]
        out[rs] = (r_lo, r_hi)
        out[ds] = (max(b[ds][0], _div(r_lo**2, tau[1])), min(b[ds][1], _div(r_hi**2, tau[0])))
        out[k] = (max(b[k][0], kap[0] * r_lo), min(b[k][1], kap[1] * r_hi))
        out[rf] = (max(b[rf][0], _div(rho[0], r_hi)), min(b[rf][1], _div(rho[1], r_lo)))
    return out


def _div(a: float, b: float) -> float:
    return a / b if b > 0 else math.inf
