"""An independent first-order algorithm for the relaxed design (eqs. 30–31): pairwise Frank–Wolfe on the capped simplex.

Maximise φ(F(η)), F(η) = Σ η_i F_i, over {l ≤ η ≤ u, Σ η = 1} (by default l = 0, u = 1/M). Each iteration moves
weight from the "away" profile (smallest gradient among those above their lower bound) to the "toward" profile
(largest gradient among those below their cap), with an exact line search; this is Wolfe's away-step idea in
its pairwise form, which converges linearly on polytopes (Lacoste-Julien & Jaggi, NeurIPS 2015).

Gradients: D (φ = log det F): g_i = tr(F⁻¹ F_i); A (φ = −tr F⁻¹): g_i = tr(F⁻² F_i). The Frank–Wolfe gap
gᵀ(s − η), with s the best vertex of the feasible set (the largest gradients filled up to their caps), bounds the
distance to the optimum: φ* − φ(η) ≤ gap. So for D the design's D-efficiency is at least exp(−gap/p).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from battlab.design.criteria import Criterion
from protocols.errors import InputError


@dataclass(frozen=True)
class FirstOrderResult:
    """Relaxed design η, its criterion value φ (larger is better), the certified gap, iterations, seconds."""

    eta: np.ndarray
    value: float
    gap: float
    iterations: int
    seconds: float
    converged: bool


def best_vertex(g: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """argmax gᵀs over {l ≤ s ≤ u, Σ s = 1}: start at l, fill the remaining mass by decreasing g."""
    s = lower.copy()
    left = 1.0 - s.sum()
    for i in np.argsort(-g, kind="stable"):
        if left <= 0:
            break
        add = min(upper[i] - s[i], left)
        s[i] += add
        left -= add
    return s


def start_point(lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """A feasible η spread as evenly as the bounds allow (raises if the bounds admit none)."""
    if lower.sum() > 1 + 1e-12 or upper.sum() < 1 - 1e-12 or np.any(lower > upper + 1e-15):
        raise InputError("design bounds are infeasible (Σ lower > 1 or Σ upper < 1)")
    room = upper - lower
    left = 1.0 - lower.sum()
    if left <= 0:
        return lower.copy()
    # water-filling: equal share, capped by room
    share = np.zeros_like(room)
    active = room > 0
    while left > 1e-15 and active.any():
        inc = left / active.sum()
        add = np.minimum(room - share, inc) * active
        share += add
        left -= add.sum()
        active &= share < room - 1e-15
    return lower + share


def _grad_value(F: np.ndarray, Fflat: np.ndarray, c: Criterion) -> tuple[np.ndarray, float, np.ndarray]:
    L = np.linalg.cholesky(F)
    Li = np.linalg.solve(L, np.eye(F.shape[0]))
    Finv = Li.T @ Li
    if c is Criterion.D:
        return Fflat @ Finv.ravel(), 2.0 * float(np.sum(np.log(np.diag(L)))), L
    F2 = Finv @ Finv
    return Fflat @ F2.ravel(), -float(np.trace(Finv)), L


def _line_search(L: np.ndarray, Delta: np.ndarray, gmax: float, c: Criterion) -> float:
    """argmax over γ ∈ [0, gmax] of φ(F + γ Δ) (φ concave in γ), with F = L Lᵀ."""
    Li = np.linalg.solve(L, np.eye(L.shape[0]))
    Mm = Li @ Delta @ Li.T
    mu, U = np.linalg.eigh((Mm + Mm.T) / 2)
    if c is Criterion.D:
        w = np.ones_like(mu)

        def d1(g: float) -> float:
            return float(np.sum(mu / (1 + g * mu)))

        def d2(g: float) -> float:
            return float(-np.sum(mu**2 / (1 + g * mu) ** 2))
    else:
        V = Li.T @ U
        w = np.sum(V * V, axis=0)

        def d1(g: float) -> float:
            return float(np.sum(w * mu / (1 + g * mu) ** 2))

        def d2(g: float) -> float:
            return float(-2 * np.sum(w * mu**2 / (1 + g * mu) ** 3))

    if d1(gmax) >= 0:
        return gmax
    if d1(0.0) <= 0:
        return 0.0
    lo, hi, g = 0.0, gmax, 0.5 * gmax
    for _ in range(60):  # safeguarded Newton on φ'(γ) = 0
        f1 = d1(g)
        if f1 > 0:
            lo = g
        else:
            hi = g
        h = d2(g)
        g_new = g - f1 / h if h < 0 else 0.5 * (lo + hi)
        if not lo < g_new < hi:
            g_new = 0.5 * (lo + hi)
        if abs(g_new - g) <= 1e-14 * max(gmax, 1e-300):
            return g_new
        g = g_new
    return g


def solve(
    Fi: np.ndarray,
    M: int,
    criterion: Criterion | str = Criterion.D,
    *,
    lower: np.ndarray | None = None,
    upper: np.ndarray | None = None,
    eta0: np.ndarray | None = None,
    tol: float = 1e-7,
    max_iter: int = 200_000,
    max_seconds: float = 60.0,
) -> FirstOrderResult:
    """Pairwise Frank–Wolfe for the D- or A-optimal relaxed design on {l ≤ η ≤ u, Σ η = 1}.

    Stops when the Frank–Wolfe gap is ≤ ``tol`` (D: absolute in log det; A: relative to |tr F⁻¹|).
    """
    c = Criterion.of(criterion)
    if c is Criterion.E:
        raise InputError("the first-order algorithm handles D and A; E-optimality is solved by the convex program")
    t0 = time.perf_counter()
    Fi = np.asarray(Fi, float)
    n, p, _ = Fi.shape
    scale = 1.0 / max(float(np.mean(np.trace(Fi, axis1=1, axis2=2))) / p, 1e-300)
    Fs = Fi * scale  # φ_D shifts by p log scale, φ_A scales by 1/scale: same minimiser
    Fflat = Fs.reshape(n, -1)
    lo = np.zeros(n) if lower is None else np.asarray(lower, float)
    up = np.full(n, 1.0 / M) if upper is None else np.asarray(upper, float)
    eta = start_point(lo, up) if eta0 is None else np.clip(np.asarray(eta0, float), lo, up)
    F = np.tensordot(eta, Fs, axes=1)
    eps = 1e-14
    it, gap, phi = 0, np.inf, -np.inf
    converged = False
    while it < max_iter:
        try:
            g, phi, L = _grad_value(F, Fflat, c)
        except np.linalg.LinAlgError:
            raise InputError("the information matrix is singular at the start point of the design") from None
        s = best_vertex(g, lo, up)
        gap = float(g @ (s - eta))
        thresh = tol if c is Criterion.D else tol * abs(phi)
        if gap <= thresh:
            converged = True
            break
        if time.perf_counter() - t0 > max_seconds:
            break
        can_in = eta < up - eps
        can_out = eta > lo + eps
        j = int(np.flatnonzero(can_in)[np.argmax(g[can_in])])
        k = int(np.flatnonzero(can_out)[np.argmin(g[can_out])])
        if g[j] <= g[k]:
            converged = True
            break
        gmax = min(up[j] - eta[j], eta[k] - lo[k])
        Delta = Fs[j] - Fs[k]
        gamma = _line_search(L, Delta, gmax, c)
        if gamma <= 0:
            break
        eta[j] += gamma
        eta[k] -= gamma
        if abs(eta[k] - lo[k]) < 1e-15:
            eta[k] = lo[k]
        if abs(eta[j] - up[j]) < 1e-15:
            eta[j] = up[j]
        F = F + gamma * Delta
        it += 1
        if it % 200 == 0:  # refresh against drift of the incremental updates
            F = np.tensordot(eta, Fs, axes=1)
    value = phi - p * np.log(scale) if c is Criterion.D else phi * scale
    gap_out = gap if c is Criterion.D else gap * scale
    return FirstOrderResult(eta, float(value), float(gap_out), it, time.perf_counter() - t0, converged)
