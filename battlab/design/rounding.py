"""From the relaxed design to M profiles: rounding, exchange, and an exact branch and bound.

* :func:`round_largest`: the M largest η (the paper's reading of eqs. 30–31, exact when the relaxation is integral);
* :func:`exchange`: Fedorov-type exchange on the integer design (swap a selected profile for an unselected one while
  the criterion improves; keeps a budget feasible);
* :func:`branch_and_bound`: the exact integer optimum (eqs. 26–28), with the first-order relaxation as the bound
  (its Frank–Wolfe gap makes the bound valid even before convergence); D and A, no budget.

:func:`integrality` reports how far a relaxed η is from a 0 / (1/M) vector.
"""

from __future__ import annotations

import heapq
import time
from dataclasses import dataclass

import numpy as np

from battlab.design import criteria, firstorder
from battlab.design.criteria import Criterion


@dataclass(frozen=True)
class Integrality:
    """How integral a relaxed design is: entries strictly between 0 and 1/M, the mass in them, the largest
    distance of an entry from {0, 1/M} (in units of 1/M)."""

    fractional: int
    fractional_mass: float
    max_distance: float
    support: int

    @property
    def integral(self) -> bool:
        return self.fractional == 0


def integrality(eta: np.ndarray, M: int, tol: float = 1e-4) -> Integrality:
    x = np.asarray(eta, float) * M
    dist = np.minimum(np.abs(x), np.abs(1.0 - x))
    frac = dist > tol
    return Integrality(int(frac.sum()), float(eta[frac].sum()), float(dist.max()), int((x > tol).sum()))


def round_largest(eta: np.ndarray, M: int, cost: np.ndarray | None = None, budget: float | None = None) -> np.ndarray:
    """Indices of the M largest η; under a budget, the largest that still fit (then the cheapest)."""
    order = np.argsort(-np.asarray(eta, float), kind="stable")
    if budget is None:
        return np.sort(order[:M])
    c = np.asarray(cost, float)
    chosen: list[int] = []
    spent = 0.0
    cheapest_rest = np.sort(c)
    for i in order:
        if len(chosen) == M:
            break
        need = M - len(chosen) - 1  # leave room for the cheapest completions
        reserve = float(np.sum(cheapest_rest[:need])) if need > 0 else 0.0
        if spent + c[i] + reserve <= budget + 1e-9:
            chosen.append(int(i))
            spent += c[i]
    if len(chosen) < M:
        for i in np.argsort(c):
            if len(chosen) == M:
                break
            if int(i) not in chosen and spent + c[i] <= budget + 1e-9:
                chosen.append(int(i))
                spent += c[i]
    return np.sort(np.array(chosen, dtype=int))


def exchange(
    Fi: np.ndarray,
    selected: np.ndarray,
    criterion: Criterion | str = Criterion.D,
    *,
    cost: np.ndarray | None = None,
    budget: float | None = None,
    max_rounds: int = 100,
) -> np.ndarray:
    """Best-improvement exchange: swap one selected profile for one unselected while the criterion improves."""
    c = Criterion.of(criterion)
    sel = [int(i) for i in selected]
    n = Fi.shape[0]
    best = criteria.value(Fi[sel].sum(axis=0), c)
    for _ in range(max_rounds):
        F = Fi[sel].sum(axis=0)
        out_idx = np.array(sel)
        in_idx = np.setdiff1d(np.arange(n), out_idx)
        if in_idx.size == 0:
            break
        # all swaps at once: F - F_out + F_in
        cand = F[None, None] - Fi[out_idx][:, None] + Fi[in_idx][None, :]
        vals = criteria.values(cand.reshape(-1, F.shape[0], F.shape[0]), c).reshape(out_idx.size, in_idx.size)
        if budget is not None:
            spent = float(np.sum(np.asarray(cost)[out_idx]))
            new_cost = spent - np.asarray(cost)[out_idx][:, None] + np.asarray(cost)[in_idx][None, :]
            vals = np.where(new_cost <= budget + 1e-9, vals, -np.inf)
        k = np.unravel_index(int(np.argmax(vals)), vals.shape)
        if not vals[k] > best + 1e-12 * max(1.0, abs(best)):
            break
        best = float(vals[k])
        sel[int(k[0])] = int(in_idx[k[1]])
    return np.sort(np.array(sel, dtype=int))


@dataclass(frozen=True)
class BranchAndBound:
    """Exact integer design (or the best found within the limits) and its certified bound."""

    selected: np.ndarray
    value: float
    bound: float
    nodes: int
    optimal: bool
    seconds: float


def branch_and_bound(
    Fi: np.ndarray,
    M: int,
    criterion: Criterion | str = Criterion.D,
    *,
    incumbent: np.ndarray | None = None,
    max_nodes: int = 2000,
    max_seconds: float = 60.0,
    tol: float = 1e-9,
) -> BranchAndBound:
    """Best-first branch and bound over m ∈ {0, 1}^L, Σ m = M, maximising φ(Σ m_i F_i) (D or A).

    A node fixes some m_i to 0 or 1; its bound is the relaxed optimum over the rest (first-order, plus its gap),
    shifted to the integer scale (φ_D(M F(η)) = φ_D(F(η)) + p log M; φ_A(M F) = φ_A(F)/M).
    """
    c = Criterion.of(criterion)
    t0 = time.perf_counter()
    Fi = np.asarray(Fi, float)
    n, p, _ = Fi.shape
    cap = 1.0 / M

    def to_int(v: float) -> float:
        return v + p * np.log(M) if c is Criterion.D else v / M

    def relax(lo: np.ndarray, up: np.ndarray) -> tuple[float, np.ndarray]:
        try:
            r = firstorder.solve(Fi, M, c, lower=lo, upper=up, tol=1e-8, max_seconds=max_seconds)
        except Exception:  # singular or infeasible node: no bound, prune
            return -np.inf, np.zeros(n)
        return to_int(r.value + max(r.gap, 0.0)), r.eta

    if incumbent is None:
        r0 = firstorder.solve(Fi, M, c)
        incumbent = exchange(Fi, round_largest(r0.eta, M), c)
    best_sel = np.sort(np.asarray(incumbent, int))
    best = criteria.value(Fi[best_sel].sum(axis=0), c)
    lo0, up0 = np.zeros(n), np.full(n, cap)
    b0, eta0 = relax(lo0, up0)
    heap: list[tuple[float, int, np.ndarray, np.ndarray, np.ndarray]] = [(-b0, 0, lo0, up0, eta0)]
    nodes, counter = 0, 1
    while heap and nodes < max_nodes and time.perf_counter() - t0 < max_seconds:
        negb, _, lo, up, eta = heapq.heappop(heap)
        bound = -negb
        if bound <= best + tol * max(1.0, abs(best)):
            continue
        nodes += 1
        x = eta * M
        free = lo < up
        frac = free & (x > 1e-6) & (x < 1 - 1e-6)
        if not frac.any():  # integral relaxed solution: a feasible design
            sel = np.flatnonzero(x > 0.5)
            if sel.size == M:
                v = criteria.value(Fi[sel].sum(axis=0), c)
                if v > best:
                    best, best_sel = v, np.sort(sel)
                if bound <= best + tol * max(1.0, abs(best)):
                    continue
            # the relaxation may still hide better integer points if the gap is loose: branch on the largest free
            cand = np.flatnonzero(free & (x > 1e-6))
            if cand.size == 0:
                continue
            j = int(cand[np.argmax(x[cand])])
        else:
            j = int(np.flatnonzero(frac)[np.argmax(np.minimum(x[frac], 1 - x[frac]))])
        for fix in (cap, 0.0):
            lo2, up2 = lo.copy(), up.copy()
            lo2[j] = up2[j] = fix
            if lo2.sum() > 1 + 1e-12 or up2.sum() < 1 - 1e-12:
                continue
            if np.count_nonzero(lo2) == M:  # fully determined
                sel = np.flatnonzero(lo2 > 0)
                v = criteria.value(Fi[sel].sum(axis=0), c)
                if v > best:
                    best, best_sel = v, np.sort(sel)
                continue
            b, e = relax(lo2, up2)
            if b > best + tol * max(1.0, abs(best)):
                heapq.heappush(heap, (-b, counter, lo2, up2, e))
                counter += 1
    open_bound = max([-h[0] for h in heap], default=-np.inf)
    optimal = not heap or open_bound <= best + tol * max(1.0, abs(best))
    return BranchAndBound(
        best_sel, float(best), float(max(best, open_bound)), nodes, bool(optimal), time.perf_counter() - t0
    )
