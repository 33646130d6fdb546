"""Design criteria on a Fisher information matrix F (eqs. 26, 30; docs/decisions.md), all as "larger is better".

* D: log det F (the paper minimises log det F⁻¹);
* A: −trace F⁻¹;
* E: λ_min(F) (the paper writes λ_max; maximising the smallest eigenvalue is E-optimality).

D-efficiency of design 1 relative to design 2: (det F₁ / det F₂)^(1/p).
"""

from __future__ import annotations

from enum import Enum

import numpy as np

from protocols.errors import InputError


class Criterion(Enum):
    """Optimality criterion."""

    D = "D"
    A = "A"
    E = "E"

    @classmethod
    def of(cls, value: str | Criterion) -> Criterion:
        if isinstance(value, Criterion):
            return value
        try:
            return cls(str(value).upper())
        except ValueError:
            raise InputError(f"unknown criterion {value!r}: expected D, A or E") from None


def logdet(F: np.ndarray) -> float:
    """log det F, −inf when F is not positive definite."""
    sign, ld = np.linalg.slogdet(np.asarray(F, float))
    return float(ld) if sign > 0 else float("-inf")


def value(F: np.ndarray, criterion: Criterion | str) -> float:
    """The criterion of F, larger is better (−inf for a singular F under D and A, ≤ 0 under E)."""
    c = Criterion.of(criterion)
    F = np.asarray(F, float)
    if c is Criterion.D:
        return logdet(F)
    if c is Criterion.E:
        return float(np.linalg.eigvalsh(F)[0])
    try:
        L = np.linalg.cholesky(F)
    except np.linalg.LinAlgError:
        return float("-inf")
    Li = np.linalg.solve(L, np.eye(F.shape[0]))
    return -float(np.sum(Li * Li))


def values(Fs: np.ndarray, criterion: Criterion | str) -> np.ndarray:
    """:func:`value` of a stack of matrices (n, p, p), vectorised for D and E."""
    c = Criterion.of(criterion)
    Fs = np.asarray(Fs, float)
    if c is Criterion.D:
        sign, ld = np.linalg.slogdet(Fs)
        return np.where(sign > 0, ld, -np.inf)
    if c is Criterion.E:
        return np.linalg.eigvalsh(Fs)[:, 0]
    return np.array([value(F, c) for F in Fs])


def d_efficiency(F1: np.ndarray, F2: np.ndarray) -> float:
    """(det F₁ / det F₂)^(1/p): 1 means as informative as design 2 (in the D sense)."""
    p = np.asarray(F1).shape[0]
    a, b = logdet(F1), logdet(F2)
    if not np.isfinite(b):
        return float("inf") if np.isfinite(a) else float("nan")
    if not np.isfinite(a):
        return 0.0
    return float(np.exp((a - b) / p))


def report_value(F: np.ndarray, criterion: Criterion | str) -> float:
    """The criterion as usually quoted: log det F (D), trace F⁻¹ (A, smaller is better), λ_min F (E)."""
    c = Criterion.of(criterion)
    v = value(F, c)
    return -v if c is Criterion.A else v


def efficiency(F1: np.ndarray, F2: np.ndarray, criterion: Criterion | str) -> float:
    """How good design 1 is relative to design 2 in the criterion's own terms (1: equal, > 1: better).

    D: (det F₁/det F₂)^(1/p); A: tr F₂⁻¹ / tr F₁⁻¹; E: λ_min F₁ / λ_min F₂.
    """
    c = Criterion.of(criterion)
    if c is Criterion.D:
        return d_efficiency(F1, F2)
    a, b = value(F1, c), value(F2, c)
    if c is Criterion.A:
        return float(b / a) if np.isfinite(a) and np.isfinite(b) and a != 0 else float("nan")
    return float(a / b) if b > 0 else float("nan")
