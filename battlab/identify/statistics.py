"""Parameter statistics after a weighted least-squares fit (paper eqs. 44–46 as corrected in docs/decisions.md).

With the weighted Jacobian J_w = W^½ ∂ŷ/∂θ̄ and weighted residuals r_w = W^½ (y − ŷ) at the estimate:

* covariance Cov = (J_wᵀ J_w)⁻¹ = (JᵀWJ)⁻¹ (eq. 44 corrected); also Cov·s² with s² = r_wᵀ r_w / (N − p);
* standard errors σ = √diag Cov (eq. 45);
* 95 % intervals θ̂ ± t(0.975, N − p) σ (eq. 46 corrected: no √N), computed in θ̄ and mapped to physical
  units (asymmetric for log-scaled parameters), intersected with the identification bounds;
* a parameter at an active bound gets a one-sided interval and is flagged; the covariance is that of all
  parameters (the others' intervals are marginal over the bound parameter, not conditional on it sitting exactly
  at the bound, which is too narrow when its true value lies inside);
* an information matrix that is singular (numerically: a singular value of the column-scaled J_w below
  ``rcond`` times the largest) is never inverted: ``valid`` is False, ``null_space`` lists the unidentifiable
  directions (unit vectors in column-scaled θ̄, as {name: coefficient}) and ``reason`` names them. A parameter
  with a component above ``IDENT_TOL`` in a null direction is not identifiable: no σ, no interval,
  ``Estimate.identifiable`` False. The others are estimable functions: their variances come from the
  pseudo-inverse (the covariance on the identifiable subspace, ``covariance_identifiable``; it equals the
  covariance of the reduced problem with any one parameter of each null direction held fixed) and their
  intervals are valid. ``covariance`` stays None.
* With all 18 parameters the null directions are the model's exact scaling symmetry (one per electrode,
  :mod:`battlab.identify.symmetry`): when all four of R_s, D_s, k, R_f of an electrode are fitted, their
  identifiable invariants (τ = R_s²/D_s, κ = k/R_s, ρ = R_f·R_s) get intervals (``invariants``) and the four
  parameters get set-identified intervals (every value on an orbit consistent with the invariants' intervals
  and all bounds; ``Estimate.identifiable`` False, ``Estimate.set_identified`` True), never intervals from the
  singular matrix.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats as _st

from battlab import parameters
from battlab.identify import symmetry

#: Relative singular value below which a direction counts as unidentifiable (the 18-parameter problem has two
#: directions near 1e-11 and the next at about 1e-4).
RCOND = 1e-8
#: A parameter whose component in a null direction exceeds this is not identifiable (the 18-parameter problem:
#: R_s, D_s, R_f, k at 0.01–0.7, all others below 1e-7).
IDENT_TOL = 1e-4


@dataclass(frozen=True)
class Estimate:
    """One parameter: value and interval in physical units, θ̄ and σ̄ in normalised units."""

    name: str
    value: float
    theta_bar: float
    sigma_bar: float | None
    sigma: float | None  # physical, delta method (dθ/dθ̄ · σ̄)
    ci95: tuple[float, float] | None
    ci95_scaled: tuple[float, float] | None
    at_bound: str | None  # "lower" | "upper" | None
    identifiable: bool = True  # False: in a null direction of the information matrix (no σ)
    set_identified: bool = False  # ci95 is the symmetry orbit's interval (:mod:`battlab.identify.symmetry`)

    def covers(self, value: float) -> bool | None:
        """Whether a physical value lies in the 95 % interval (None without an interval)."""
        if self.ci95 is None:
            return None
        lo, hi = self.ci95
        return bool(lo * (1 - 1e-12) <= value <= hi * (1 + 1e-12)) if lo > 0 else bool(lo <= value <= hi)


@dataclass(frozen=True)
class Statistics:
    """Eqs. 44–46 at a fit's solution (normalised parameters θ̄, names in fit order)."""

    names: tuple[str, ...]
    theta_bar: np.ndarray
    n_obs: int
    dof: int
    t_value: float
    covariance: np.ndarray | None  # (p, p) in θ̄; rows/cols of bound parameters hold their marginal only
    covariance_scaled: np.ndarray | None
    correlation: np.ndarray | None
    s2: float  # r_wᵀ r_w / (N − p): 1 when the weights match the noise
    condition: float  # condition number of the column-scaled weighted Jacobian
    estimates: tuple[Estimate, ...] = field(default_factory=tuple)
    valid: bool = True
    reason: str | None = None
    unidentifiable: tuple[str, ...] = ()
    null_space: tuple[dict[str, float], ...] = ()  # unidentifiable directions, column-scaled θ̄
    covariance_identifiable: np.ndarray | None = None  # pseudo-inverse (p, p), valid between estimable parameters
    invariants: tuple[symmetry.Invariant, ...] = ()  # identifiable combinations of symmetric parameters

    def __getitem__(self, name: str) -> Estimate:
        for e in self.estimates:
            if e.name == name:
                return e
        raise KeyError(name)

    def table(self) -> list[dict[str, object]]:
        """Rows for printing: name, value, ci95, σ, θ̄, at_bound."""
        return [
            {
                "name": e.name,
                "value": e.value,
                "ci95": e.ci95,
                "sigma": e.sigma,
                "theta_bar": e.theta_bar,
                "at_bound": e.at_bound,
                "identifiable": e.identifiable,
            }
            for e in self.estimates
        ]


def correlation(cov: np.ndarray | None) -> np.ndarray | None:
    """Correlation matrix of a covariance (NaN rows stay NaN)."""
    if cov is None:
        return None
    d = np.sqrt(np.abs(np.diag(cov)))
    with np.errstate(invalid="ignore", divide="ignore"):
        return cov / np.outer(d, d)


def _interval(
    name: str, th: float, half: float, side: str | None, box: tuple[float, float] = (0.0, 1.0)
) -> tuple[float, float]:
    spec = parameters.spec(name)
    lo, hi = th - half, th + half
    if side == "upper":
        hi = th
    elif side == "lower":
        lo = th
    lo, hi = max(lo, box[0]), min(hi, box[1])
    return spec.denormalise(lo), spec.denormalise(hi)


def pseudo_covariance(J: np.ndarray, rcond: float = RCOND) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(JᵀJ)⁻¹ = D⁻¹ V S⁻² Vᵀ D⁻¹ with D the column norms of J (a zero column is a null direction of its own; the
    pseudo-inverse if singular: singular values of J D⁻¹ below ``rcond`` × the largest are dropped), with those
    singular values S, the right singular vectors Vᵀ and which of them were kept."""
    norms = np.linalg.norm(J, axis=0)
    norms[norms == 0] = 1.0
    _, s, Vt = np.linalg.svd(J / norms, full_matrices=False)
    keep = s > rcond * s[0] if s.size else np.zeros(0, bool)
    return (Vt[keep].T / s[keep] ** 2) @ Vt[keep] / np.outer(norms, norms), s, Vt, keep


def compute(
    names: Sequence[str],
    theta_bar: np.ndarray,
    J_w: np.ndarray,
    r_w: np.ndarray,
    at_bound: Sequence[str | None] | None = None,
    *,
    rcond: float = RCOND,
    box: tuple[np.ndarray, np.ndarray] | None = None,
) -> Statistics:
    """Statistics of a weighted fit: ``J_w`` (N, p) = W^½ ∂ŷ/∂θ̄, ``r_w`` (N,) weighted residuals; ``box``: the
    search box in θ̄ (lower, upper; default [0, 1]) the intervals are intersected with."""
    names = tuple(names)
    th = np.asarray(theta_bar, float)
    J = np.asarray(J_w, float)
    r = np.asarray(r_w, float)
    n, p = J.shape
    bound = list(at_bound) if at_bound is not None else [None] * p
    dof = n - p
    s2 = float(r @ r / dof) if dof > 0 else float("nan")
    tval = float(_st.t.ppf(0.975, dof)) if dof > 0 else float("nan")

    def invalid(reason: str, cond: float = float("inf")) -> Statistics:
        est = tuple(
            Estimate(nm, parameters.spec(nm).denormalise(float(t)), float(t), None, None, None, None, b)
            for nm, t, b in zip(names, th, bound, strict=True)
        )
        return Statistics(names, th, n, dof, tval, None, None, None, s2, cond, est, False, reason)

    if dof <= 0:
        return invalid(f"{n} observations for {p} parameters: no degrees of freedom")
    # the covariance is that of all parameters, those at a bound included: the others' intervals are marginal over
    # the bound parameters' uncertainty (conditional ones, with a bound parameter fixed at the bound, are too narrow
    # when its true value lies inside: measured 86 % coverage instead of 95 % on the virtual truth)
    if not np.all(np.isfinite(J)):
        return invalid("the Jacobian has non-finite entries")
    dead = [nm for nm, z in zip(names, np.linalg.norm(J, axis=0) == 0, strict=True) if z]
    cov_all, s, Vt, keep = pseudo_covariance(J, rcond)
    cond = (float(s[0] / s[-1]) if s[-1] > 0 else float("inf")) if s.size else float("nan")
    null = Vt[~keep]
    ok = ~(np.linalg.norm(null, axis=0) > IDENT_TOL) if null.size else np.ones(p, bool)
    sig = np.sqrt(np.where(ok, np.diag(cov_all), np.nan))
    corr = correlation(cov_all)
    cov = cov_all.copy()
    for a in (cov, corr):  # rows/cols of non-identifiable parameters carry no information
        a[~ok, :] = np.nan
        a[:, ~ok] = np.nan
    est = []
    for k, nm in enumerate(names):
        spec = parameters.spec(nm)
        value = spec.denormalise(float(th[k]))
        sb = float(sig[k])
        if not np.isfinite(sb):
            est.append(Estimate(nm, value, float(th[k]), None, None, None, None, bound[k], False))
            continue
        edges = (0.0, 1.0) if box is None else (float(box[0][k]), float(box[1][k]))
        ci = _interval(nm, float(th[k]), tval * sb, bound[k], edges)
        ci_s = _interval(nm, float(th[k]), tval * sb * np.sqrt(s2), bound[k], edges)
        est.append(Estimate(nm, value, float(th[k]), sb, spec.dvalue_dnormalised(value) * sb, ci, ci_s, bound[k]))
    invs: dict[str, symmetry.Invariant] = {}
    electrodes = symmetry.complete_electrodes(names)
    if electrodes:  # invariants from the pseudo-inverse (estimable functions)
        invs = symmetry.invariants(names, th, cov_all, tval)
        orbit = symmetry.orbit_intervals(invs, electrodes)
        for k, nm in enumerate(names):
            if nm in orbit:
                e = est[k]
                est[k] = Estimate(nm, e.value, e.theta_bar, None, None, orbit[nm], None, e.at_bound, False, True)
    notes = []
    directions: tuple[dict[str, float], ...] = ()
    unident = tuple(nm for k, nm in enumerate(names) if not ok[k])
    if null.size:
        directions = tuple({nm: float(c) for nm, c in zip(names, v, strict=True) if abs(c) > IDENT_TOL} for v in null)
        combos = "; ".join(
            ", ".join(f"{nm} ({c:+.2f})" for nm, c in sorted(dd.items(), key=lambda x: -abs(x[1])) if abs(c) > 0.01)
            for dd in directions
        )
        notes.append(
            f"singular information matrix ({len(null)} null direction(s), condition {cond:.3g}): the combination(s) "
            f"{combos} are not identifiable from these data; no covariance intervals for {', '.join(unident)}; "
            "the other intervals use the covariance on the identifiable subspace"
        )
    if invs:
        notes.append(
            "R_s, D_s, k, R_f of electrode(s) " + ", ".join(electrodes) + " are moved by the model's exact "
            "scaling symmetry: their intervals are set-identified (orbits consistent with the invariants "
            + ", ".join(f"{i.name} = {i.value:.4g} [{i.ci95[0]:.4g}, {i.ci95[1]:.4g}]" for i in invs.values())
            + " and the bounds)"
        )
    if any(bound):
        notes.append(
            "one-sided intervals for parameters at a bound: "
            + ", ".join(f"{nm} ({b})" for nm, b in zip(names, bound, strict=True) if b)
        )
    if dead:
        notes.insert(0, f"zero sensitivity to {', '.join(dead)}")
    singular = bool(null.size)
    return Statistics(
        names,
        th,
        n,
        dof,
        tval,
        None if singular else cov,
        None if singular else cov * s2,
        None if singular else corr,
        s2,
        cond,
        tuple(est),
        not singular,
        "; ".join(notes) or None,
        unident,
        directions,
        cov,
        tuple(invs.values()),
    )
