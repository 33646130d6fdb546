"""The bounded Gauss–Newton step of the fit's polish: the step that minimises the linearised cost inside the
parameter box, with the decrease it predicts, checked against a steepest-descent step so that an unfinished
bounded least-squares solve is never read as convergence."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class GaussNewtonStep:
    """A bounded Gauss–Newton step δ in θ̄ and the decrease of the linearised cost ½‖r + Jδ‖² it predicts [½χ²
    units, ≥ 0]. ``failed`` says why no step could be trusted (then δ = 0 and ``predicted`` is NaN: no prediction,
    so no convergence can be read from it)."""

    step: np.ndarray
    predicted: float
    failed: str | None = None


def bounded_gauss_newton(
    x: np.ndarray, J: np.ndarray, r: np.ndarray, upper: np.ndarray | None = None, lower: np.ndarray | None = None
) -> GaussNewtonStep:
    """The Gauss–Newton step δ from ``x`` that minimises the linearised cost ½‖r + Jδ‖² inside the box
    ``lower`` ≤ x + δ ≤ ``upper`` (default [0, 1]; bounded linear least squares on the column-scaled Jacobian), and
    the decrease it predicts.

    Unbounded, the step along the nearly dependent directions (singular values 1e-4 of the largest) runs far
    outside the box; inside it the prediction stays meaningful.

    δ = 0 is inside the box, so the minimiser predicts a decrease ≥ 0, and at least that of the best step along
    the projected steepest descent (:func:`_steepest_descent_decrease`). A solution that predicts less did not
    solve the subproblem (scipy's BVLS stops after one iteration per variable by default, which an ill-conditioned
    Jacobian whose minimum has several parameters on a bound can exceed: on a 7-parameter problem it returned a
    step predicting −0.33 where +0.23 was there to gain). Such a solution is never taken as a prediction: BVLS is
    given more iterations, the interior-point solver (TRF) is tried next, and if neither solves it the step is
    reported failed. A prediction within round-off of zero is accepted only where steepest descent finds nothing
    either (a stationary point).
    """
    from scipy.optimize import lsq_linear

    norms = np.linalg.norm(J, axis=0)
    norms[norms == 0] = 1.0
    A = J / norms
    top = np.ones_like(x) if upper is None else np.asarray(upper, float)
    bottom = np.zeros_like(x) if lower is None else np.asarray(lower, float)
    lo, hi = (bottom - x) * norms, (top - x) * norms
    hi = np.maximum(hi, lo + 1e-300)
    r2 = float(r @ r)
    slack = 1e-9 * r2  # round-off of ½(‖r‖² − ‖r + Jδ‖²), far below any predicted_tol in use
    floor = steepest_descent_decrease(A, r, lo, hi)
    tried = []
    for method in ("bvls", "trf"):
        sol = lsq_linear(A, -r, bounds=(lo, hi), method=method, tol=1e-12, max_iter=max(100, 10 * x.size))
        step = sol.x / norms
        rr = r + J @ step
        dec = 0.5 * (r2 - float(rr @ rr))
        if sol.status > 0 and dec >= max(floor, 0.0) - slack:
            return GaussNewtonStep(step, max(dec, 0.0))
        tried.append(f"{method.upper()} {dec:.3g}" + ("" if sol.status > 0 else " at its iteration limit"))
    return GaussNewtonStep(
        np.zeros_like(x),
        float("nan"),
        f"predicted decrease {', '.join(tried)}, below the {floor:.3g} of steepest descent inside the bounds "
        "(active set not found, or a rank-deficient Jacobian)",
    )


def steepest_descent_decrease(A: np.ndarray, r: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> float:
    """The decrease of ½‖r + Az‖² along the projected steepest descent: the best of z = clip(α d, lo, hi) with
    d = −Aᵀr, for α at the unbounded line minimum (and fractions of it) and at the first bound. Each z is inside
    lo ≤ z ≤ hi (lo ≤ 0 ≤ hi), so this is a lower bound of what the minimiser of the bounded problem predicts."""
    d = -(A.T @ r)
    dd = float(d @ d)
    Ad = A @ d
    curv = float(Ad @ Ad)
    if dd == 0.0 or curv == 0.0:
        return 0.0
    up, down = d > 0, d < 0
    first = min(np.min(hi[up] / d[up], initial=np.inf), np.min(lo[down] / d[down], initial=np.inf))
    r2 = float(r @ r)
    best = 0.0
    for a in (dd / curv, 0.3 * dd / curv, 0.1 * dd / curv, first):
        if np.isfinite(a) and a > 0:
            rz = r + A @ np.clip(a * d, lo, hi)
            best = max(best, 0.5 * (r2 - float(rz @ rz)))
    return best


#: Fractions of the bounded Gauss–Newton step tried in turn by :func:`_polish`.
