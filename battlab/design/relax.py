"""The convex relaxation of the design (eqs. 30–31, 33–35) in cvxpy: Clarabel, with SCS as the fallback.

maximise φ(Σ η_i F_i) subject to 0 ≤ η_i ≤ 1/M, Σ η_i = 1 and optionally M cᵀη ≤ B (eq. 35), with
φ = log det (D), −tr(·)⁻¹ (A) or λ_min (E). The F_i of a battery library span many orders of magnitude (a
parameter with a narrow range, like t_c⁰, has tiny θ̄-sensitivities) and some parameters are nearly collinear, so
the problem is posed on the congruent matrices F̃_i = Tᵀ F_i T that whiten the candidates' mean information
(:func:`whitening`); each criterion is rewritten exactly: log det F = log det F̃ − 2 log |det T|;
tr F⁻¹ = matrix_frac(Tᵀ, F̃); λ_min(F) ≥ t ⇔ F̃ − t TᵀT ⪰ 0 (A and E objectives further scaled to order one).
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass

import numpy as np

from battlab.design import criteria
from battlab.design.criteria import Criterion
from protocols.errors import InputError


@dataclass(frozen=True)
class RelaxedResult:
    """Relaxed design η (Σ η = 1), criterion value φ(Σ η_i F_i) (larger is better), solver and status."""

    eta: np.ndarray
    value: float
    solver: str
    status: str
    seconds: float


def whitening(Fi: np.ndarray) -> np.ndarray:
    """T with Tᵀ F̄ T = I for the mean information F̄ of the candidates (T = S V Λ^(-1/2) from the eigenpairs of
    the unit-diagonal S F̄ S); the diagonal S alone when F̄ is numerically singular."""
    Fbar = np.mean(Fi, axis=0)
    d = np.diag(Fbar)
    s = np.where(d > 0, 1.0 / np.sqrt(np.where(d > 0, d, 1.0)), 1.0)
    C = Fbar * np.outer(s, s)
    lam, V = np.linalg.eigh((C + C.T) / 2)
    if lam[0] <= 1e-13 * lam[-1]:
        return np.diag(s)
    return (s[:, None] * V) / np.sqrt(lam)[None, :]


def _solve_restricted(
    Ft: np.ndarray,
    T: np.ndarray,
    M: int,
    c: Criterion,
    cand: np.ndarray,
    up: np.ndarray,
    lo: np.ndarray | None,
    cost: np.ndarray | None,
    budget: float | None,
    order: list[str],
    errors: list[str],
) -> tuple[np.ndarray, str, str] | None:
    """Solve over the candidates ``cand`` only (the others at η = 0); None if no solver succeeded."""
    import cvxpy as cp

    n, p = cand.size, Ft.shape[1]
    eta = cp.Variable(n, nonneg=True)
    X = cp.Variable((p, p), symmetric=True)
    cons = [cp.sum(eta) == 1, eta <= up[cand], cp.vec(X, order="C") == Ft[cand].reshape(n, -1).T @ eta]
    if lo is not None:
        cons.append(eta >= lo[cand])
    if budget is not None:
        cons.append(M * (cost[cand] @ eta) <= budget)  # type: ignore[index]
    if c is Criterion.D:
        obj = cp.Maximize(cp.log_det(X))
    elif c is Criterion.A:
        a = float(np.trace(T @ T.T))  # tr F⁻¹ / a is of order one (solver tolerances are absolute)
        obj = cp.Minimize(cp.matrix_frac(T.T / np.sqrt(a), X))
    else:
        t = cp.Variable()  # λ_min(F) / b with b = λ_min(F̄): of order one
        TT = T.T @ T
        TT = (TT + TT.T) / 2
        cons.append(X - t * (TT / np.linalg.eigvalsh(TT)[-1]) >> 0)
        obj = cp.Maximize(t)
    prob = cp.Problem(obj, cons)
    for name in order:
        try:
            kw = {"max_iters": 20000, "eps": 1e-7} if name == "SCS" else {}
            with warnings.catch_warnings():  # an inaccurate solution is reported through its status
                warnings.simplefilter("ignore", UserWarning)
                prob.solve(solver=name, **kw)
        except (cp.error.SolverError, ValueError) as exc:
            errors.append(f"{name}: {exc}")
            continue
        if prob.status in ("optimal", "optimal_inaccurate") and eta.value is not None:
            e = np.zeros(Ft.shape[0])
            e[cand] = np.asarray(eta.value, float)
            return e, name, str(prob.status)
        errors.append(f"{name}: {prob.status}")
    return None


def supergradient(F: np.ndarray, Fi: np.ndarray, c: Criterion) -> np.ndarray:
    """∂φ/∂η_i at F = Σ η_i F_i: tr(F⁻¹F_i) (D), tr(F⁻²F_i) (A), vᵀF_i v for the lowest eigenvector v (E)."""
    n = Fi.shape[0]
    flat = Fi.reshape(n, -1)
    if c is Criterion.E:
        v = np.linalg.eigh(F)[1][:, 0]
        return flat @ np.outer(v, v).ravel()
    Finv = np.linalg.inv(F)
    Finv = (Finv + Finv.T) / 2
    return flat @ (Finv if c is Criterion.D else Finv @ Finv).ravel()


def certificate(
    eta: np.ndarray,
    Fi: np.ndarray,
    c: Criterion,
    lo: np.ndarray,
    up: np.ndarray,
    cost: np.ndarray | None = None,
    budget: float | None = None,
    M: int = 1,
) -> tuple[float, np.ndarray, np.ndarray]:
    """(gap, g, s): φ* − φ(η) ≤ gap = gᵀ(s − η), s the best vertex of the feasible set for the supergradient g
    (concavity)."""
    from battlab.design.firstorder import best_vertex

    F = np.tensordot(eta, Fi, axes=1)
    g = supergradient(F, Fi, c)
    if budget is None:
        s = best_vertex(g, lo, up)
    else:
        from scipy.optimize import linprog

        res = linprog(
            -g,
            A_ub=[M * np.asarray(cost, float)],
            b_ub=[budget],
            A_eq=[np.ones(g.size)],
            b_eq=[1.0],
            bounds=list(zip(lo, up, strict=True)),
            method="highs",
        )
        s = res.x if res.status == 0 else eta
    return float(g @ (s - eta)), g, s


def solve(
    Fi: np.ndarray,
    M: int,
    criterion: Criterion | str = Criterion.D,
    *,
    cost: np.ndarray | None = None,
    budget: float | None = None,
    solver: str | None = None,
    lower: np.ndarray | None = None,
    upper: np.ndarray | None = None,
    restrict: int | None = 64,
    tol: float = 1e-5,
) -> RelaxedResult:
    """Solve the relaxed design; ``solver`` None tries Clarabel then SCS. Raises InputError if both fail.

    ``restrict`` (column generation): solve over a working set of that many candidates (those with the best
    information on their own), then add every candidate whose supergradient beats the working set's threshold
    and re-solve, until the Frank–Wolfe certificate over *all* candidates is ≤ ``tol`` (D: in log det; A, E:
    relative) or nothing is left to add. None: all candidates at once.
    """
    c = Criterion.of(criterion)
    Fi = np.asarray(Fi, float)
    n, p, _ = Fi.shape
    if n < M:
        raise InputError(f"need at least M = {M} candidate profiles, have {n}")
    if budget is not None and cost is None:
        raise InputError("a budget needs per-profile costs")
    t0 = time.perf_counter()
    T = whitening(Fi)
    Ft = np.einsum("ba,lbc,cd->lad", T, Fi, T)
    up = np.full(n, 1.0 / M) if upper is None else np.asarray(upper, float)
    lo = np.zeros(n) if lower is None else np.asarray(lower, float)
    order = [solver.upper()] if solver else ["CLARABEL", "SCS"]
    errors: list[str] = []
    if restrict is None or restrict >= n:
        cand = np.arange(n)
    else:
        own = np.trace(Ft, axis1=1, axis2=2)
        first = set(np.argsort(-own)[:restrict].tolist()) | set(np.flatnonzero(lo > 0).tolist())
        cand = np.array(sorted(first))
    rounds = 0
    previous = -np.inf
    rel_gap = float("nan")
    while True:
        rounds += 1
        got = _solve_restricted(Ft, T, M, c, cand, up, lower if lower is None else lo, cost, budget, order, errors)
        if got is None:
            raise InputError(f"the {c.value}-optimal relaxation could not be solved ({'; '.join(errors)})")
        e, name, status = got
        e = np.clip(e, lo, up)
        e /= e.sum()
        if cand.size == n:
            break
        now = criteria.value(np.tensordot(e, Fi, axes=1), c)
        if c is Criterion.E and now <= previous + 1e-6 * abs(previous):
            break  # λ_min is not smooth: a supergradient certificate may never close; stop when adding stalls
        previous = now
        # D is invariant under the congruence (up to a constant); A and E are not: certify on the original F_i
        gap, g, vertex = certificate(e, Ft if c is Criterion.D else Fi, c, lo, up, cost, budget, M)
        F = np.tensordot(e, Fi, axes=1)
        scale = 1.0 if c is Criterion.D else max(abs(criteria.value(F, c)), 1e-300)
        rel_gap = gap / scale
        if gap <= tol * scale:
            break
        inside = np.zeros(n, bool)
        inside[cand] = True
        free = inside & (e > lo + 1e-9) & (e < up - 1e-9)
        tau = float(np.min(g[free])) if free.any() else float(np.min(g[inside & (e > lo + 1e-9)]))
        add = np.flatnonzero(~inside & ((g > tau) | (vertex > 0)))
        if add.size == 0:
            if c is Criterion.E:
                status += ", λ_min supergradient certificate inconclusive (nonsmooth)"
            break
        add = add[np.argsort(-g[add])][: max(restrict or 0, 16)]
        cand = np.union1d(cand, add)
    F = np.tensordot(e, Fi, axes=1)
    return RelaxedResult(
        e,
        criteria.value(F, c),
        name,
        f"{status} ({rounds} rounds, {cand.size} candidates, certified gap {rel_gap:.1e})",
        time.perf_counter() - t0,
    )
