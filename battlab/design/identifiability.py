"""Identifiability: orthogonalised sensitivity ranking, collinearity indices and parameter groups (Fig. 4, Table 9).

Successive orthogonalisation (the paper's Gram–Schmidt on S_yᵀ S_y): take the sensitivity column of largest norm,
orthogonalise every other column against it, take the largest remaining one, and so on; the norm of a column
when it is taken is that parameter's *orthogonalised magnitude* — what it adds to the voltage beyond the
parameters taken before it. This is a QR factorisation with column pivoting (the magnitudes are |R_kk|).

Per profile the columns are the weighted sensitivities S_i / q_i (eqs. 22, 40); the library ranking averages each
parameter's magnitude over the profiles (the paper's Fig. 4). Beside it, a pivoted QR of the stacked weighted
sensitivities of the whole library (= the information of all profiles together). Groups: the parameters sorted by
magnitude are cut into k contiguous groups that minimise the spread of log10 magnitude within groups (optimal 1-D
k-means, "natural breaks"). Collinearity index of a parameter set K (Brun et al., Water Res. 2001):
γ_K = 1/√λ_min(S̃_Kᵀ S̃_K) with unit-norm columns S̃; above 10–15 the set is practically not identifiable.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.linalg as sla

from battlab import parameters

#: The paper's Table 9 (defined once, in :mod:`battlab.parameters`).
PAPER_TABLE9 = parameters.TABLE9_GROUPS


def successive_orthogonalisation(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gram–Schmidt with largest-norm pivoting on the columns of S (n × p).

    Returns (order, magnitude): ``order`` the column indices in the order taken, ``magnitude[j]`` the norm of
    column j orthogonalised against the columns taken before it. Modified Gram–Schmidt, applied twice.
    """
    A = np.array(S, dtype=float, copy=True)
    n, p = A.shape
    order: list[int] = []
    mag = np.zeros(p)
    left = list(range(p))
    for _ in range(min(n, p)):
        norms = np.linalg.norm(A[:, left], axis=0)
        k = left[int(np.argmax(norms))]
        mag[k] = float(np.linalg.norm(A[:, k]))
        order.append(k)
        left.remove(k)
        if mag[k] == 0.0:
            break
        q = A[:, k] / mag[k]
        for _twice in range(2):
            A[:, left] -= np.outer(q, q @ A[:, left])
    order += left
    return np.array(order), mag


def pivoted_magnitudes(S: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """As :func:`successive_orthogonalisation`, by LAPACK's pivoted Householder QR (faster, same result)."""
    S = np.asarray(S, float)
    R, perm = sla.qr(S, mode="r", pivoting=True)
    mag = np.zeros(S.shape[1])
    d = np.abs(np.diag(R))
    mag[perm[: d.size]] = d
    return perm, mag


@dataclass(frozen=True)
class Ranking:
    """Library ranking: per-profile magnitudes (L × p), their mean, the stacked pivoted-QR magnitudes."""

    names: tuple[str, ...]
    ids: tuple[Any, ...]
    per_profile: np.ndarray
    mean: np.ndarray
    stacked: np.ndarray
    stacked_order: np.ndarray
    weighted: bool = True

    @property
    def order(self) -> np.ndarray:
        """Parameter indices by decreasing mean orthogonalised magnitude."""
        return np.argsort(-self.mean, kind="stable")

    def ranked_names(self, by: str = "mean") -> list[str]:
        idx = self.order if by == "mean" else self.stacked_order
        return [self.names[i] for i in idx]

    def to_dict(self) -> dict[str, Any]:
        return {
            "weighted": self.weighted,
            "n_profiles": len(self.ids),
            "mean": {n: float(v) for n, v in zip(self.names, self.mean, strict=True)},
            "stacked": {n: float(v) for n, v in zip(self.names, self.stacked, strict=True)},
            "order_mean": self.ranked_names("mean"),
            "order_stacked": self.ranked_names("stacked"),
        }


def rank(W: np.ndarray, names: Sequence[str], ids: Sequence[Any] = (), *, weighted: bool = True) -> Ranking:
    """Rank from per-profile square-root information W (L × r × p; rows: weighted sensitivities or R_i/q_i)."""
    W = np.asarray(W, float)
    per = np.array([pivoted_magnitudes(Wi)[1] for Wi in W])
    perm, stacked = pivoted_magnitudes(W.reshape(-1, W.shape[-1]))
    return Ranking(tuple(names), tuple(ids), per, per.mean(axis=0), stacked, perm, weighted)


def natural_breaks(values: np.ndarray, k: int) -> list[np.ndarray]:
    """Split ``values`` into k groups of consecutive ranks minimising the within-group sum of squares (1-D k-means
    by dynamic programming; exact). Returns index arrays, group 1 = largest values."""
    v = np.asarray(values, float)
    order = np.argsort(-v, kind="stable")
    x = v[order]
    n = x.size
    if not 1 <= k <= n:
        raise ValueError(f"need 1 <= k <= {n} groups, got {k}")
    c1 = np.concatenate([[0.0], np.cumsum(x)])
    c2 = np.concatenate([[0.0], np.cumsum(x * x)])

    def sse(i: int, j: int) -> float:  # x[i:j]
        s, s2, m = c1[j] - c1[i], c2[j] - c2[i], j - i
        return float(s2 - s * s / m)

    cost = np.full((k + 1, n + 1), np.inf)
    arg = np.zeros((k + 1, n + 1), dtype=int)
    cost[0, 0] = 0.0
    for g in range(1, k + 1):
        for j in range(g, n + 1):
            best, where = np.inf, g - 1
            for i in range(g - 1, j):
                c = cost[g - 1, i] + sse(i, j)
                if c < best - 1e-15:
                    best, where = c, i
            cost[g, j], arg[g, j] = best, where
    cuts, j = [], n
    for g in range(k, 0, -1):
        i = arg[g, j]
        cuts.append((i, j))
        j = i
    return [order[i:j] for i, j in reversed(cuts)]


def group(ranking: Ranking, k: int = 4, *, by: str = "mean") -> list[list[str]]:
    """k parameter groups by orthogonalised magnitude (natural breaks of log10 magnitude), largest first."""
    mags = ranking.mean if by == "mean" else ranking.stacked
    pos = mags[mags > 0]
    floor = (pos.min() if pos.size else 1.0) * 1e-3
    logs = np.log10(np.maximum(mags, floor))
    return [[ranking.names[i] for i in g] for g in natural_breaks(logs, k)]


def collinearity_index(G: np.ndarray, idx: Sequence[int]) -> float:
    """γ_K = 1/√λ_min of the normalised Gram matrix of the columns ``idx`` (G = Sᵀ S). inf when singular."""
    idx = list(idx)
    if len(idx) < 2:
        return 1.0
    sub = G[np.ix_(idx, idx)]
    d = np.sqrt(np.diag(sub))
    if np.any(d == 0):
        return float("inf")
    lam = float(np.linalg.eigvalsh(sub / np.outer(d, d))[0])
    return float("inf") if lam <= 0 else 1.0 / np.sqrt(lam)


@dataclass(frozen=True)
class Collinearity:
    """Collinearity indices: per group, per cumulative set of groups, the pairwise cosine matrix and, per
    parameter, its most collinear partner."""

    groups: list[float]
    cumulative: list[float]
    all_parameters: float
    cosine: np.ndarray
    partner: dict[str, tuple[str, float]]

    def to_dict(self) -> dict[str, Any]:
        return {
            "groups": self.groups,
            "cumulative": self.cumulative,
            "all": self.all_parameters,
            "partner": {k: {"parameter": v[0], "cosine": v[1]} for k, v in self.partner.items()},
        }


def collinearity(G: np.ndarray, names: Sequence[str], groups: Sequence[Sequence[str]]) -> Collinearity:
    """Collinearity report from the total Gram matrix G (p × p) of the weighted sensitivities."""
    names = list(names)
    d = np.sqrt(np.maximum(np.diag(G), 1e-300))
    cos = G / np.outer(d, d)
    partner = {}
    for i, n in enumerate(names):
        c = np.abs(cos[i]).copy()
        c[i] = -1.0
        j = int(np.argmax(c))
        partner[n] = (names[j], float(cos[i, j]))
    gi = [[names.index(n) for n in g] for g in groups]
    cum: list[float] = []
    acc: list[int] = []
    for g in gi:
        acc = acc + g
        cum.append(collinearity_index(G, acc))
    return Collinearity(
        [collinearity_index(G, g) for g in gi], cum, collinearity_index(G, range(len(names))), cos, partner
    )


def compare_with_paper(groups: Sequence[Sequence[str]]) -> list[dict[str, Any]]:
    """Per parameter: our group and the paper's (Table 9)."""
    ours = {n: k + 1 for k, g in enumerate(groups) for n in g}
    paper = {n: k + 1 for k, g in enumerate(PAPER_TABLE9) for n in g}
    return [
        {"parameter": n, "symbol": parameters.SPECS[n].symbol, "ours": ours.get(n), "paper": paper.get(n)}
        for n in parameters.NAMES
        if n in ours or n in paper
    ]
