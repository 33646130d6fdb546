"""Statistics of a weighted fit (eqs. 44-46 corrected): covariance, t intervals, bounds, singular information."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import stats

from battlab import parameters
from battlab.identify import statistics

NAMES = ("R_s_n", "D_s_n", "eps_e_n")


def _linear_problem(seed: int, n: int = 40) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, n)
    J = 50 * np.column_stack([np.ones(n), t, t**2])  # weighted Jacobian (unit noise)
    truth = np.array([0.3, 0.5, 0.6])
    y = J @ truth + rng.normal(0, 1.0, n)
    est = np.linalg.lstsq(J, y, rcond=None)[0]
    return J, y - J @ est, est


def test_covariance_is_inverse_information_and_interval_uses_t_without_sqrt_n() -> None:
    J, r, est = _linear_problem(0)
    st = statistics.compute(NAMES, est, J, r)
    assert st.valid
    np.testing.assert_allclose(st.covariance, np.linalg.inv(J.T @ J), rtol=1e-10)
    assert st.t_value == pytest.approx(stats.t.ppf(0.975, 40 - 3))
    np.testing.assert_allclose(st.covariance_scaled, st.covariance * (r @ r) / 37, rtol=1e-10)
    e = st["eps_e_n"]  # linear parameter: interval is symmetric in physical units
    spec = parameters.SPECS["eps_e_n"]
    half = st.t_value * np.sqrt(st.covariance[2, 2]) * (spec.upper - spec.lower)
    assert e.ci95 == pytest.approx((e.value - half, e.value + half))
    d = st["D_s_n"]  # log parameter: interval is multiplicative, asymmetric
    assert d.ci95[0] < d.value < d.ci95[1]
    assert d.value / d.ci95[0] == pytest.approx(d.ci95[1] / d.value, rel=1e-9)
    assert abs(st.correlation[0, 1]) <= 1 and st.correlation[0, 0] == pytest.approx(1)


def test_coverage_of_linear_problem_is_nominal() -> None:
    covered = []
    for seed in range(400):
        J, r, est = _linear_problem(seed)
        st = statistics.compute(NAMES, est, J, r)
        for k, name in enumerate(NAMES):
            covered.append(st[name].covers(parameters.SPECS[name].denormalise([0.3, 0.5, 0.6][k])))
    assert 0.93 <= np.mean(covered) <= 0.97


def test_singular_information_gives_no_intervals() -> None:
    J, r, est = _linear_problem(1)
    J = J.copy()
    J[:, 2] = 2 * J[:, 1]  # two parameters with proportional sensitivities
    st = statistics.compute(NAMES, est, J, r)
    assert not st.valid and st.covariance is None
    assert "singular" in st.reason and "D_s_n" in st.reason and "eps_e_n" in st.reason
    assert st.unidentifiable == ("D_s_n", "eps_e_n") and len(st.null_space) == 1
    assert set(st.null_space[0]) == {"D_s_n", "eps_e_n"}
    assert st["D_s_n"].ci95 is None and st["eps_e_n"].ci95 is None and not st["eps_e_n"].identifiable
    # R_s_n is orthogonal to the null direction: its interval is that of the reduced problem (eps_e_n dropped)
    e = st["R_s_n"]
    assert e.identifiable and e.ci95 is not None
    red = np.linalg.inv(J[:, :2].T @ J[:, :2])
    assert e.sigma_bar == pytest.approx(np.sqrt(red[0, 0]), rel=1e-8)
    J[:, 2] = 0.0
    st = statistics.compute(NAMES, est, J, r)
    assert not st.valid and "zero sensitivity to eps_e_n" in st.reason and st.unidentifiable == ("eps_e_n",)
    assert st["eps_e_n"].ci95 is None and st["D_s_n"].ci95 is not None


def test_unidentifiable_directions_of_a_dependent_group_are_named() -> None:
    rng = np.random.default_rng(3)
    n = 60
    names = ("R_s_n", "D_s_n", "R_f_n", "k_n", "eps_e_n")
    base = rng.normal(size=(n, 3))
    J = 30 * np.column_stack(
        [
            base[:, 0],
            base[:, 1],
            base[:, 0] - base[:, 1] + 1e-13 * rng.normal(size=n),
            base[:, 0] + 2 * base[:, 1],
            base[:, 2],
        ]
    )
    st = statistics.compute(names, np.full(5, 0.5), J, rng.normal(size=n))
    assert not st.valid and len(st.null_space) == 2
    assert set(st.unidentifiable) == {"R_s_n", "D_s_n", "R_f_n", "k_n"}
    assert st["eps_e_n"].ci95 is not None and st["eps_e_n"].identifiable
    assert st.covariance_identifiable is not None


def test_parameter_at_bound_gets_a_flagged_one_sided_interval() -> None:
    J, r, est = _linear_problem(2)
    est = est.copy()
    est[2] = 1.0
    st = statistics.compute(NAMES, est, J, r, [None, None, "upper"])
    e = st["eps_e_n"]
    assert e.at_bound == "upper"
    assert e.ci95[1] == pytest.approx(parameters.SPECS["eps_e_n"].upper)
    assert e.ci95[0] < e.ci95[1]
    assert "one-sided" in st.reason
    # the others' statistics are marginal over the bound parameter (not conditional on it: wider)
    np.testing.assert_allclose(st.covariance, np.linalg.inv(J.T @ J), rtol=1e-10)
    assert (np.diag(st.covariance)[:2] > np.diag(np.linalg.inv(J[:, :2].T @ J[:, :2]))).all()


def test_no_degrees_of_freedom_is_invalid() -> None:
    J = np.eye(3)
    st = statistics.compute(NAMES, np.full(3, 0.5), J, np.zeros(3))
    assert not st.valid and "degrees of freedom" in st.reason


def test_all_parameters_at_bounds_is_handled() -> None:
    J, r, _ = _linear_problem(3)
    st = statistics.compute(NAMES, np.array([0.0, 1.0, 0.0]), J, r, ["lower", "upper", "lower"])
    assert np.isfinite(st.condition)
    for e in st.estimates:
        assert e.at_bound is not None and e.ci95 is not None
        spec = parameters.SPECS[e.name]
        end, bound = (e.ci95[0], spec.lower) if e.at_bound == "lower" else (e.ci95[1], spec.upper)
        assert end == pytest.approx(bound)
