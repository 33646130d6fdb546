"""Group-wise, cumulative optimal designs: for group k, the information restricted to the
parameters of groups 1..k (the others fixed at their nominal values), as the paper identifies them cumulatively.

For each stage: a singularity check, the convex relaxation (cvxpy), the independent first-order solution, the
rounding to M profiles (largest η, then exchange; optionally the exact branch and bound), the integrality of the
relaxed solution and its gap to the rounded design, and the efficiency against random designs and against the
conventional test set.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from battlab import parameters
from battlab.design import criteria, firstorder, relax, rounding
from battlab.design.criteria import Criterion
from battlab.design.information import Information
from protocols.errors import InputError

NEAR_SINGULAR = 1e-10
"""Smallest eigenvalue of the scaled information (unit diagonal) below which a group is not identifiable: a
collinearity index above 1e5."""


class SingularInformation(InputError):
    """The library cannot identify a set of parameters: the message names the offending directions."""


@dataclass(frozen=True)
class Settings:
    """Design settings: M profiles per group, criterion, optional budget (eq. 35) on ``cost`` (duration [s],
    throughput [Ah] or user-given per-profile costs), exact branch and bound, random designs for comparison.

    ``on_singular``: "error" raises :class:`SingularInformation` naming the directions no profile resolves;
    "project" designs on the identifiable subspace (the information projected onto the complement of those
    directions, which no experiment of the library can inform) and reports them."""

    M: int = 5
    criterion: Criterion = Criterion.D
    budget: float | None = None
    cost: str = "duration"
    costs: dict[Any, float] | None = None
    cumulative: bool = True
    exact: bool = False
    exact_seconds: float = 30.0
    n_random: int = 1000
    seed: int = 0
    solver: str | None = None
    on_singular: str = "error"


@dataclass
class GroupDesign:
    """The design of one stage (see the module docstring); values of φ are on the integer scale Σ_{selected} F_i."""

    index: int
    parameters: list[str]
    new_parameters: list[str]
    selected: list[Any]
    criterion: str
    value: float
    logdet: float
    relaxed_value: float
    relaxation_gap: float
    integrality: rounding.Integrality
    eta: dict[Any, float]
    first_order: dict[str, Any]
    random: dict[str, Any]
    conventional: dict[str, Any] | None
    exact: dict[str, Any] | None
    solver: str
    solve_seconds: float
    cost_total: float
    unidentifiable: list[NullDirection] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return {
            "group": self.index,
            "parameters": self.parameters,
            "new_parameters": self.new_parameters,
            "selected": self.selected,
            "logdet": self.logdet,
            "criterion_value": criteria_report(self.value, self.criterion),
            "relaxed_value": criteria_report(self.relaxed_value, self.criterion),
            "relaxation_gap": self.relaxation_gap,
            "integrality": {
                "integral": self.integrality.integral,
                "fractional_entries": self.integrality.fractional,
                "fractional_mass": self.integrality.fractional_mass,
                "max_distance": self.integrality.max_distance,
                "support": self.integrality.support,
            },
            "eta": {str(k): v for k, v in self.eta.items()},
            "first_order": self.first_order,
            "random": self.random,
            "conventional": self.conventional,
            "exact": self.exact,
            "solver": self.solver,
            "solve_seconds": self.solve_seconds,
            "cost_total": self.cost_total,
            "unidentifiable": [n.to_dict() for n in self.unidentifiable],
            "logdet_space": "identifiable subspace (scaled coordinates)" if self.unidentifiable else "theta_bar",
        }


def criteria_report(v: float, criterion: str) -> float:
    """φ as usually quoted: log det (D), trace F⁻¹ (A), λ_min (E)."""
    return -v if criterion == "A" else v


@dataclass(frozen=True)
class NullDirection:
    """A parameter direction (in θ̄, largest component ±1) that the library's information cannot resolve."""

    vector: np.ndarray
    names: tuple[str, ...]
    eigenvalue: float

    @property
    def collinearity_index(self) -> float:
        return float(1 / np.sqrt(self.eigenvalue)) if self.eigenvalue > 0 else float("inf")

    def describe(self) -> str:
        v = self.vector
        if self.eigenvalue == 0.0 and np.count_nonzero(v) == 1:
            return f"{self.names[int(np.flatnonzero(v)[0])]} (no information at all: zero sensitivity in every profile)"
        terms = [f"{v[j]:+.3g}·{self.names[j]}" for j in np.argsort(-np.abs(v)) if abs(v[j]) >= 0.02]
        return f"[{' '.join(terms)}] (collinearity index {self.collinearity_index:.2g})"

    def to_dict(self) -> dict[str, Any]:
        return {
            "direction": {n: float(x) for n, x in zip(self.names, self.vector, strict=True) if abs(x) >= 1e-3},
            "scaled_eigenvalue": self.eigenvalue,
            "collinearity_index": self.collinearity_index if np.isfinite(self.collinearity_index) else None,
        }


def _scaled(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(C, s): C = S F S with unit diagonal (S = diag s; s_j = 1/√F_jj, 0 where F_jj = 0)."""
    d = np.diag(F).copy()
    s = np.where(d > 0, 1.0 / np.sqrt(np.where(d > 0, d, 1.0)), 0.0)
    C = F * np.outer(s, s)
    return (C + C.T) / 2, s


def null_directions(F: np.ndarray, names: Sequence[str], threshold: float = NEAR_SINGULAR) -> list[NullDirection]:
    """Directions of θ̄ along which F is (near) singular: zero-information parameters, and eigenvectors of the
    unit-diagonal scaled F with eigenvalue < ``threshold`` × the largest (collinearity index > threshold^-½)."""
    names = tuple(names)
    C, s = _scaled(F)
    out = [NullDirection(np.eye(len(names))[j], names, 0.0) for j in np.flatnonzero(s == 0)]
    lam, V = np.linalg.eigh(C)
    for k in range(len(lam)):
        if lam[k] >= threshold * lam[-1]:
            break
        if np.all(np.abs(V[s > 0, k]) < 1e-12):
            continue  # a zero-information parameter, listed above
        v = V[:, k] * s  # back to θ̄
        out.append(NullDirection(v / np.max(np.abs(v)), names, float(lam[k])))
    return out


def check_information(F: np.ndarray, names: Sequence[str], what: str, threshold: float = NEAR_SINGULAR) -> None:
    """Raise :class:`SingularInformation` naming the directions the information matrix F cannot resolve."""
    nulls = null_directions(F, names, threshold)
    if nulls:
        raise SingularInformation(
            f"{what}: the information matrix is near singular: no profile of the library separates the "
            f"direction(s) {'; '.join(n.describe() for n in nulls)} in normalised parameters θ̄; regroup, fix one "
            "of the parameters involved, or design on the identifiable subspace (--singular project)"
        )


def identifiable_basis(F: np.ndarray, threshold: float = NEAR_SINGULAR) -> np.ndarray:
    """B (p × q): maps scaled coordinates of the identifiable subspace to θ̄ (θ̄ = B c); Bᵀ F B is well posed."""
    C, s = _scaled(F)
    lam, V = np.linalg.eigh(C)
    keep = lam >= threshold * lam[-1]
    return s[:, None] * V[:, keep]


def _restrict(Fi: np.ndarray, idx: Sequence[int]) -> np.ndarray:
    ix = np.asarray(idx)
    return Fi[:, ix][:, :, ix]


def design_stage(
    Fi_all: np.ndarray,
    info: Information,
    params: Sequence[str],
    s: Settings,
    *,
    index: int = 1,
    new: Sequence[str] = (),
    conventional: Information | None = None,
) -> GroupDesign:
    """One stage: the design for ``params`` over the usable profiles (see the module docstring)."""
    c = s.criterion
    M = s.M
    idx = [info.index(n) for n in params]
    Fi = _restrict(Fi_all, idx)
    n, p = Fi.shape[0], len(idx)
    if n < M:
        raise InputError(f"group {index}: only {n} usable profiles for M = {M}")
    what = f"group {index} ({', '.join(params)})"
    nulls: list[NullDirection] = []
    B = None
    if s.on_singular == "project":
        nulls = null_directions(Fi.sum(axis=0), params)
        if nulls:
            B = identifiable_basis(Fi.sum(axis=0))
            Fi = np.einsum("pa,lpq,qb->lab", B, Fi, B)
            p = Fi.shape[1]
    elif s.on_singular == "error":
        check_information(Fi.sum(axis=0), params, what)
    else:
        raise InputError(f"on_singular must be 'error' or 'project', got {s.on_singular!r}")
    cost = _costs(info, s)
    t0 = time.perf_counter()
    rel = relax.solve(Fi, M, c, cost=cost, budget=s.budget, solver=s.solver)
    fo = _first_order_check(Fi, M, c, rel, s, cost)
    best = rel
    if fo.get("eta") is not None and fo["value"] > rel.value:  # keep the better relaxed optimum (reported)
        best = relax.RelaxedResult(fo.pop("eta"), fo["value"], "pairwise Frank-Wolfe", "better than " + rel.solver, 0.0)
    fo.pop("eta", None)
    rel = best
    sel = rounding.round_largest(rel.eta, M, cost, s.budget)
    if sel.size < M:
        raise InputError(f"{what}: no {M} profiles fit the budget {s.budget:g} ({s.cost})")
    sel = rounding.exchange(Fi, sel, c, cost=cost, budget=s.budget)
    solve_seconds = time.perf_counter() - t0
    exact = None
    if s.exact and s.budget is None and c is not Criterion.E:
        bb = rounding.branch_and_bound(Fi, M, c, incumbent=sel, max_seconds=s.exact_seconds)
        exact = {
            "optimal": bb.optimal,
            "value": criteria_report(bb.value, c.value),
            "bound": criteria_report(bb.bound, c.value),
            "nodes": bb.nodes,
            "seconds": bb.seconds,
            "selected": [info.ids[i] for i in bb.selected],
        }
        if bb.value > criteria.value(Fi[sel].sum(axis=0), c):
            sel = bb.selected
    F_sel = Fi[sel].sum(axis=0)
    v_sel = criteria.value(F_sel, c)
    relaxed_int = _integer_scale(rel.value, c, M, p)
    gap = relaxed_int - v_sel if c is not Criterion.A else (-v_sel) - (-relaxed_int)
    return GroupDesign(
        index=index,
        parameters=list(params),
        new_parameters=list(new) or list(params),
        selected=[info.ids[i] for i in sel],
        criterion=c.value,
        value=v_sel,
        logdet=criteria.logdet(F_sel),
        relaxed_value=relaxed_int,
        relaxation_gap=float(gap),
        integrality=rounding.integrality(rel.eta, M),
        eta={info.ids[i]: float(rel.eta[i]) for i in np.flatnonzero(rel.eta * M > 1e-4)},
        first_order=fo,
        random=_random(Fi, F_sel, c, M, s, cost),
        conventional=_vs_conventional(conventional, idx, F_sel, c, float(np.sum(_durations(info)[sel])), B),
        exact=exact,
        solver=f"{rel.solver}: {rel.status}",
        solve_seconds=solve_seconds,
        cost_total=float(np.sum(cost[sel])) if cost is not None else float(np.sum(_durations(info)[sel])),
        unidentifiable=nulls,
    )


def _integer_scale(v: float, c: Criterion, M: int, p: int) -> float:
    """φ(M F(η)) from φ(F(η))."""
    if c is Criterion.D:
        return v + p * np.log(M)
    if c is Criterion.A:
        return v / M
    return v * M


def _durations(info: Information) -> np.ndarray:
    return np.array([m["duration"] for m in info.meta], float)


def _costs(info: Information, s: Settings) -> np.ndarray | None:
    if s.costs is not None:
        missing = [pid for pid in info.ids if pid not in s.costs and str(pid) not in s.costs]
        if missing:
            raise InputError(f"costs: no cost for profile(s) {missing[:10]}")
        return np.array([s.costs.get(pid, s.costs.get(str(pid))) for pid in info.ids], float)
    if s.budget is None:
        return None
    return info.cost(s.cost)


def _first_order_check(
    Fi: np.ndarray, M: int, c: Criterion, rel: relax.RelaxedResult, s: Settings, cost: np.ndarray | None
) -> dict[str, Any]:
    """The independent algorithm's optimum and its agreement with the convex solver."""
    p = Fi.shape[1]
    if c is Criterion.E or s.budget is not None:
        other = "SCS" if not rel.solver.upper().startswith("SCS") else "CLARABEL"
        try:
            alt = relax.solve(Fi, M, c, cost=cost, budget=s.budget, solver=other)
        except InputError as exc:
            return {"method": other, "error": str(exc)}
        rel_diff = abs(alt.value - rel.value) / max(abs(rel.value), 1e-300) if c is not Criterion.D else None
        eff = float(np.exp((alt.value - rel.value) / p)) if c is Criterion.D else None
        return {
            "method": f"{other} (independent solver)",
            "value": alt.value,
            "d_efficiency": eff,
            "relative_difference": rel_diff,
            "agree": bool((eff is not None and abs(eff - 1) <= 1e-4) or (rel_diff is not None and rel_diff <= 1e-3)),
        }
    fo = firstorder.solve(Fi, M, c, tol=1e-9)
    if c is Criterion.D:
        eff = float(np.exp((fo.value - rel.value) / p))
        agree = min(eff, 1 / eff) >= 1 - 1e-4
        return {
            "method": "pairwise Frank-Wolfe",
            "value": fo.value,
            "gap": fo.gap,
            "iterations": fo.iterations,
            "seconds": fo.seconds,
            "d_efficiency": eff,
            "agree": bool(agree),
            "eta": fo.eta,
        }
    rel_diff = abs(fo.value - rel.value) / abs(rel.value)
    F1, F2 = np.tensordot(fo.eta, Fi, axes=1), np.tensordot(rel.eta, Fi, axes=1)
    return {
        "method": "pairwise Frank-Wolfe",
        "value": fo.value,
        "gap": fo.gap,
        "iterations": fo.iterations,
        "seconds": fo.seconds,
        "relative_difference": rel_diff,
        "d_efficiency": criteria.d_efficiency(F1, F2),
        "agree": bool(rel_diff <= 1e-4),
        "eta": fo.eta,
    }


def _random(
    Fi: np.ndarray, F_sel: np.ndarray, c: Criterion, M: int, s: Settings, cost: np.ndarray | None
) -> dict[str, Any]:
    """Efficiency of random M-subsets (within the budget) relative to the design."""
    rng = np.random.default_rng(s.seed)
    n = Fi.shape[0]
    effs = []
    tries = 0
    while len(effs) < s.n_random and tries < 20 * s.n_random:
        tries += 1
        pick = rng.choice(n, M, replace=False)
        if s.budget is not None and cost is not None and cost[pick].sum() > s.budget:
            continue
        effs.append(criteria.efficiency(Fi[pick].sum(axis=0), F_sel, c))
    e = np.array(effs, float)
    if e.size == 0:
        return {"n": 0}
    return {
        "n": int(e.size),
        "median": float(np.nanmedian(e)),
        "p90": float(np.nanpercentile(e, 90)),
        "max": float(np.nanmax(e)),
        "better_than_design": int(np.sum(e > 1 + 1e-9)),
    }


def _vs_conventional(
    conv: Information | None,
    idx: Sequence[int],
    F_sel: np.ndarray,
    c: Criterion,
    hours_design_s: float,
    B: np.ndarray | None = None,
) -> dict[str, Any] | None:
    if conv is None:
        return None
    F_conv = _restrict(conv.F, idx).sum(axis=0)
    if B is not None:
        F_conv = B.T @ F_conv @ B
    hours_conv = float(np.sum(_durations(conv))) / 3600
    eff = criteria.efficiency(F_sel, F_conv, c)
    return {
        "efficiency": eff,
        "efficiency_per_hour": eff * hours_conv / (hours_design_s / 3600) if hours_design_s > 0 else None,
        "d_efficiency": criteria.d_efficiency(F_sel, F_conv),
        "design_hours": hours_design_s / 3600,
        "conventional_hours": hours_conv,
        "tests": list(conv.ids),
    }


def design_groups(
    info: Information,
    groups: Sequence[Sequence[str]],
    settings: Settings | None = None,
    conventional: Information | None = None,
) -> list[GroupDesign]:
    """One design per group; with ``settings.cumulative`` group k uses the parameters of groups 1..k."""
    s = settings or Settings()
    seen: set[str] = set()
    for k, g in enumerate(groups, start=1):
        if not g:
            raise InputError(f"group {k} is empty")
        for n in g:
            parameters.spec(n)
            if n not in info.names:
                raise InputError(f"group {k}: parameter {n!r} has no sensitivities in the store")
            if n in seen:
                raise InputError(f"parameter {n!r} appears more than once in the groups (again in group {k})")
            seen.add(n)
    Fi = info.F
    out, acc = [], []
    for k, g in enumerate(groups, start=1):
        acc = acc + list(g) if s.cumulative else list(g)
        out.append(design_stage(Fi, info, acc, s, index=k, new=g, conventional=conventional))
    return out
