"""Orthogonalised ranking, natural-breaks grouping and collinearity indices (battlab.design.identifiability)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from battlab import parameters
from battlab.design import identifiability as ident


def _random_S(seed: int, n: int = 40, p: int = 6) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.normal(size=(n, p)) * 10 ** rng.uniform(-3, 2, p)


@pytest.mark.parametrize("seed", range(5))
def test_successive_orthogonalisation_is_pivoted_qr(seed: int) -> None:
    S = _random_S(seed)
    order, mag = ident.successive_orthogonalisation(S)
    perm, mag_qr = ident.pivoted_magnitudes(S)
    np.testing.assert_array_equal(order, perm)
    np.testing.assert_allclose(mag, mag_qr, rtol=1e-9)


def test_orthogonal_columns_keep_their_norms_and_order() -> None:
    Q, _ = np.linalg.qr(np.random.default_rng(1).normal(size=(30, 4)))
    S = Q * np.array([1.0, 100.0, 0.1, 10.0])
    order, mag = ident.successive_orthogonalisation(S)
    assert order.tolist() == [1, 3, 0, 2]
    np.testing.assert_allclose(mag, [1.0, 100.0, 0.1, 10.0])


def test_a_copied_column_adds_nothing() -> None:
    S = _random_S(2, p=3)
    S = np.column_stack([S, 0.5 * S[:, 0]])  # column 3 is collinear with column 0 (smaller)
    _, mag = ident.successive_orthogonalisation(S)
    assert mag[3] < 1e-10 * mag.max()
    G = S.T @ S
    assert ident.collinearity_index(G, [0, 3]) == float("inf") or ident.collinearity_index(G, [0, 3]) > 1e6


def test_collinearity_index_of_orthogonal_columns_is_one() -> None:
    Q, _ = np.linalg.qr(np.random.default_rng(3).normal(size=(20, 5)))
    G = (Q * [1, 2, 3, 4, 5]).T @ (Q * [1, 2, 3, 4, 5])
    assert ident.collinearity_index(G, range(5)) == pytest.approx(1.0)
    assert ident.collinearity_index(G, [2]) == 1.0


def test_collinearity_index_matches_definition() -> None:
    S = _random_S(4, p=4)
    Sn = S / np.linalg.norm(S, axis=0)
    expected = 1 / np.sqrt(np.linalg.eigvalsh(Sn.T @ Sn)[0])
    assert ident.collinearity_index(S.T @ S, range(4)) == pytest.approx(expected, rel=1e-9)


def _brute_breaks(x: np.ndarray, k: int) -> float:
    xs = np.sort(x)[::-1]
    best = np.inf
    for cuts in itertools.combinations(range(1, xs.size), k - 1):
        parts = np.split(xs, cuts)
        best = min(best, sum(float(np.sum((q - q.mean()) ** 2)) for q in parts))
    return best


@settings(max_examples=40, deadline=None)
@given(st.lists(st.floats(-10, 10), min_size=4, max_size=9), st.integers(1, 4))
def test_natural_breaks_is_optimal(values: list[float], k: int) -> None:
    x = np.array(values)
    k = min(k, x.size)
    groups = ident.natural_breaks(x, k)
    assert sorted(np.concatenate(groups).tolist()) == list(range(x.size))
    assert len(groups) == k
    sse = sum(float(np.sum((x[g] - x[g].mean()) ** 2)) for g in groups)
    assert sse == pytest.approx(_brute_breaks(x, k), abs=1e-9)
    means = [x[g].mean() for g in groups]
    assert means == sorted(means, reverse=True)  # group 1 = largest


def test_rank_and_group_on_separated_magnitudes() -> None:
    rng = np.random.default_rng(5)
    names = list(parameters.NAMES[:6])
    scales = np.array([1e3, 1.1e3, 1.0, 1.2, 1e-3, 0.9e-3])
    W = rng.normal(size=(8, 30, 6)) * scales
    r = ident.rank(W, names, ids=range(8))
    groups = ident.group(r, 3)
    assert [sorted(g) for g in groups] == [sorted(names[:2]), sorted(names[2:4]), sorted(names[4:])]
    assert r.per_profile.shape == (8, 6)
    np.testing.assert_allclose(r.mean, r.per_profile.mean(axis=0))
    assert set(r.ranked_names("stacked")) == set(names)
    d = r.to_dict()
    assert d["order_mean"][:2] == [names[i] for i in np.argsort(-r.mean)[:2]]


def test_collinearity_report_and_paper_comparison() -> None:
    S = _random_S(6, p=4)
    S[:, 3] = S[:, 2] + 1e-6 * S[:, 1]
    names = list(parameters.NAMES[:4])
    col = ident.collinearity(S.T @ S, names, [names[:2], names[2:]])
    assert col.groups[1] > 1e3 and col.groups[0] < 1e3
    assert col.cumulative[-1] >= col.groups[1]
    assert col.partner[names[3]][0] == names[2]
    rows = ident.compare_with_paper([names[:2], names[2:]])
    assert {r["parameter"] for r in rows} == set(parameters.NAMES)
    paper = {r["parameter"]: r["paper"] for r in rows}
    assert paper["R_s_n"] == 1 and paper["t_plus"] == 4
    assert sum(len(g) for g in ident.PAPER_TABLE9) == 18
