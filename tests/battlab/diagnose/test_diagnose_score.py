"""Score tests: projection on the base directions, false alarms under white and correlated error, power,
calibration and indistinguishable causes, on synthetic residuals with known truth."""

from __future__ import annotations

import numpy as np
import pytest

from battlab.diagnose.score import (
    calibrate,
    detectable_size,
    indistinguishable,
    project_out,
    rank_causes,
    score_test,
    summary,
)

N = 7200
T = np.arange(N, dtype=float)
J = np.column_stack([np.ones(N), np.sin(2 * np.pi * T / 3000), T / N])  # base-parameter sensitivities
S = np.cos(2 * np.pi * T / 700)[:, None]  # an extension the base cannot mimic
W = np.full(N, 1e6)  # 1 / (1 mV)²


def ar1(rng: np.random.Generator, phi: float, sd: float) -> np.ndarray:
    """Stationary AR(1) model error, correlation time 1/(1 − phi) samples."""
    e = np.empty(N)
    e[0] = rng.normal() * sd
    innov = rng.normal(size=N) * sd * np.sqrt(1 - phi**2)
    for k in range(1, N):
        e[k] = phi * e[k - 1] + innov[k]
    return e


def base_fit(y: np.ndarray) -> np.ndarray:
    """The residual after the (linear) base model has absorbed what it can."""
    return y - J @ np.linalg.lstsq(J, y, rcond=None)[0]


def rejection_rate(make, variance: str, n: int = 100, seed: int = 0) -> float:
    rng = np.random.default_rng(seed)
    hits = sum(score_test("x", base_fit(make(rng)), J, S, W, T, variance=variance).p_value < 0.05 for _ in range(n))
    return hits / n


def test_projection_is_w_orthogonal_to_the_base() -> None:
    St = project_out(J, np.column_stack([S[:, 0], T**2 / N**2]), W)
    assert np.max(np.abs(J.T @ (W[:, None] * St))) < 1e-6 * np.max(np.abs(J.T @ (W[:, None] * S)))


def test_an_extension_the_base_can_mimic_has_no_informative_direction() -> None:
    mimic = (2.0 * J[:, 1] - J[:, 2])[:, None]
    res = score_test("mimic", base_fit(np.random.default_rng(1).normal(0, 1e-3, N)), J, mimic, W, T)
    assert res.dof == 0 and res.statistic == 0.0 and res.p_value == 1.0
    assert res.projected_norm < 1e-6


def test_white_noise_false_alarms_near_nominal() -> None:
    rate = rejection_rate(lambda rng: rng.normal(0, 1e-3, N), "block")
    assert rate <= 0.12


def test_correlated_model_error_fools_the_white_variance_but_not_the_block_variance() -> None:
    make = lambda rng: ar1(rng, 0.99, 3e-3)  # noqa: E731
    assert rejection_rate(make, "white") >= 0.5
    assert rejection_rate(make, "block") <= 0.15


def test_a_hidden_effect_is_found() -> None:
    rng = np.random.default_rng(3)
    detected = 0
    for _ in range(30):
        y = ar1(rng, 0.99, 3e-3) + 3e-3 * S[:, 0]
        detected += score_test("x", base_fit(y), J, S, W, T).p_value < 0.01
    assert detected >= 27


def test_ranking_puts_the_true_cause_first_and_names_twins() -> None:
    rng = np.random.default_rng(4)
    other = np.sign(np.sin(2 * np.pi * T / 1900))[:, None]
    twin = S + 1e-3 * rng.normal(size=(N, 1))
    y = base_fit(rng.normal(0, 1e-3, N) + 1e-3 * S[:, 0])
    res = [score_test(c, y, J, s, W, T) for c, s in (("other", other), ("true", S), ("twin", twin))]
    ranked = rank_causes(res)
    assert {ranked[0].cause, ranked[1].cause} == {"true", "twin"} and ranked[2].cause == "other"
    pairs = indistinguishable(res, W)
    assert [(a, b) for a, b, _ in pairs] == [("true", "twin")]
    rows = summary(res)
    assert rows[0]["score"] >= rows[1]["score"] >= rows[2]["score"]


def test_calibration_takes_the_null_quantile() -> None:
    th = calibrate(np.arange(1, 101, dtype=float), alpha=0.05)
    assert th.value == 96.0 and th.n_null == 100
    with pytest.raises(ValueError):
        calibrate([])


def test_real_extension_directions_name_a_hidden_contact_resistance() -> None:
    """The catalog's own directions (exact sensitivities at "off", battlab.diagnose.directions) on synthetic data
    with a 3 mΩ contact resistance hidden in it and 0.5 mV white noise (white variance): contact_resistance ranks
    first (measured LM/dof 760, the next electrolyte 308)."""
    import battlab
    from battlab.diagnose.directions import extension_directions
    from protocols import Profile

    cell = battlab.Cell.load("nca18650")
    t = np.arange(0.0, 1801.0)
    level = np.array([0.0, -1.0, 0.0, 0.5, -2.0, 0.0, 1.0, -0.5])  # C-rates, 60 s each, repeated
    prof = Profile(t, 2.7 * level[(t // 60).astype(int) % level.size])
    truth = battlab.simulate(cell.with_extension("contact_resistance", R_c=0.003), prof, soc0=0.6).voltage
    y = truth + np.random.default_rng(5).normal(0.0, 5e-4, t.size)
    base_names = ("D_s_n", "D_s_p", "k_p", "c_e0")
    dirs = extension_directions(cell, prof, 0.6, base_names)
    assert {d.cause for d in dirs} == set(battlab.parameters.EXTENSIONS) - {"double_layer"}
    w = np.full(t.size, 1.0 / 5e-4**2)
    results = [score_test(d.cause, y - d.voltage, d.J, d.S, w, t, variance="white") for d in dirs]  # white noise
    ranked = rank_causes(results)
    assert ranked[0].cause == "contact_resistance", summary(results)


def test_the_detectable_size_is_detected_about_half_the_time_and_a_mimicked_column_never() -> None:
    """An effect of the detectable size along a direction the base cannot mimic passes the test at that threshold
    in somewhat under half of the noise draws (the size is where the noncentrality equals the critical value;
    measured 23/60); twice the size nearly always (58/60); a column along the base directions has no detectable
    size."""
    rng = np.random.default_rng(5)
    p_thr = 0.01 / 7
    S2 = np.column_stack([S[:, 0], J[:, 2]])  # one free column, one the base mimics exactly
    size = detectable_size(base_fit(rng.normal(size=N) * 1e-3), J, S2, W, T, p_thr, block_s=240.0)
    assert np.isfinite(size[0]) and size[1] == np.inf
    hits = {1.0: 0, 2.0: 0}
    for _ in range(60):
        noise = rng.normal(size=N) * 1e-3
        for f in hits:
            r = base_fit(noise + f * size[0] * S[:, 0])
            hits[f] += score_test("x", r, J, S2[:, :1], W, T, block_s=240.0).p_value < p_thr
    assert 0.25 <= hits[1.0] / 60 <= 0.75, hits
    assert hits[2.0] / 60 >= 0.9, hits
