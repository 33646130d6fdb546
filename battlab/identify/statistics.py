"""Parameter statistics after a weighted least-squares fit (paper eqs. 44–46 as corrected in DESIGN.md).

With the weighted Jacobian J_w = W^½ ∂ŷ/∂θ̄ and weighted residuals r_w = W^½ (y − ŷ) at the estimate:

* covariance Cov = (J_wᵀ J_w)⁻¹ = (JᵀWJ)⁻¹ (eq. 44 corrected); also Cov·s² with s² = r_wᵀ r_w / (N − p);
* standard errors σ = √diag Cov (eq. 45);
* 95 % intervals θ̂ ± t(0.975, N − p) σ (eq. 46 corrected: no √N), computed in θ̄ and mapped to physical
  units (asymmetric for log-scaled parameters), intersected with the identification bounds;
* a parameter at an active bound gets a one-sided interval and is flagged; the other parameters' statistics
  are those of the reduced problem with it held at the bound;
* an information matrix that is singular (numerically: reciprocal condition number of the column-scaled
  J_w below ``rcond``) gives no intervals at all: ``valid`` is False and ``reason`` names the parameters of
  the null space.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from scipy import stats as _st

from battlab import parameters

RCOND = 1e-10


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
    condition: float  # condition number of the column-scaled weighted Jacobian of the free parameters
    estimates: tuple[Estimate, ...] = field(default_factory=tuple)
    valid: bool = True
    reason: str | None = None

    def __getitem__(self, name: str) -> Estimate:
        for e in self.estimates:
            if e.name == name:
                return e
        raise KeyError(name)

    def table(self) -> list[dict[str, object]]:
        """Rows for printing: name, value, ci95, σ, θ̄, at_bound."""
        return [
            {"name": e.name, "value": e.value, "ci95": e.ci95, "sigma": e.sigma, "theta_bar": e.theta_bar,
             "at_bound": e.at_bound}
            for e in self.estimates
        ]


def _interval(name: str, th: float, half: float, side: str | None) -> tuple[float, float]:
    spec = parameters.spec(name)
    lo, hi = th - half, th + half
    if side == "upper":
        hi = th
    elif side == "lower":
        lo = th
    lo, hi = max(lo, 0.0), min(hi, 1.0)
    return spec.denormalise(lo), spec.denormalise(hi)


def compute(
    names: Sequence[str],
    theta_bar: np.ndarray,
    J_w: np.ndarray,
    r_w: np.ndarray,
    at_bound: Sequence[str | None] | None = None,
    *,
    rcond: float = RCOND,
) -> Statistics:
    """Statistics of a weighted fit: ``J_w`` (N, p) = W^½ ∂ŷ/∂θ̄, ``r_w`` (N,) weighted residuals."""
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
    free = np.array([b is None for b in bound])
    Jf = J[:, free]
    norms = np.linalg.norm(Jf, axis=0)
    if np.any(norms == 0) or not np.all(np.isfinite(Jf)):
        dead = [nm for nm, f in zip(np.array(names)[free], norms == 0, strict=True) if f]
        return invalid(f"singular information matrix: zero sensitivity to {', '.join(dead) or 'a parameter'}")
    U, s, Vt = np.linalg.svd(Jf / norms, full_matrices=False)
    cond = float(s[0] / s[-1]) if s[-1] > 0 else float("inf")
    if s[-1] <= rcond * s[0]:
        v = Vt[-1]
        involved = [f"{nm} ({c:+.2f})" for nm, c in zip(np.array(names)[free], v, strict=True) if abs(c) > 0.2]
        return invalid(
            f"singular information matrix (condition {cond:.3g}): the combination {', '.join(involved)} "
            "is not identifiable from these data", cond,
        )
    # Cov of the free parameters: (J_fᵀ J_f)⁻¹ = D⁻¹ V S⁻² Vᵀ D⁻¹ with D = diag(norms)
    cov_f = (Vt.T / s**2) @ Vt / np.outer(norms, norms)
    cov = np.full((p, p), np.nan)
    idx = np.flatnonzero(free)
    cov[np.ix_(idx, idx)] = cov_f
    for k in np.flatnonzero(~free):  # marginal variance of a bound parameter: from the full matrix if possible
        full = J.T @ J
        try:
            cov[k, k] = float(np.linalg.inv(full)[k, k])
            if not np.isfinite(cov[k, k]) or cov[k, k] <= 0:
                raise np.linalg.LinAlgError
        except np.linalg.LinAlgError:
            cov[k, k] = 1.0 / float(J[:, k] @ J[:, k]) if J[:, k] @ J[:, k] > 0 else np.nan
    sig = np.sqrt(np.diag(cov))
    corr = cov_f / np.outer(np.sqrt(np.diag(cov_f)), np.sqrt(np.diag(cov_f)))
    corr_full = np.full((p, p), np.nan)
    corr_full[np.ix_(idx, idx)] = corr
    est = []
    for k, nm in enumerate(names):
        spec = parameters.spec(nm)
        value = spec.denormalise(float(th[k]))
        sb = float(sig[k])
        if not np.isfinite(sb):
            est.append(Estimate(nm, value, float(th[k]), None, None, None, None, bound[k]))
            continue
        ci = _interval(nm, float(th[k]), tval * sb, bound[k])
        ci_s = _interval(nm, float(th[k]), tval * sb * np.sqrt(s2), bound[k])
        est.append(Estimate(nm, value, float(th[k]), sb, spec.dvalue_dnormalised(value) * sb, ci, ci_s, bound[k]))
    reason = None
    if (~free).any():
        reason = "one-sided intervals for parameters at a bound: " + ", ".join(
            f"{nm} ({b})" for nm, b in zip(names, bound, strict=True) if b
        )
    return Statistics(names, th, n, dof, tval, cov, cov * s2, corr_full, s2, cond, tuple(est), True, reason)
