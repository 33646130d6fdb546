"""Residual analysis on synthetic data with known structure: the feature an error depends on comes first,
white noise looks white at s² ≈ 1, and drift looks slow and correlated."""

from __future__ import annotations

import numpy as np
import pytest

from battlab.diagnose.residuals import analyse, features

T = np.arange(0.0, 7200.0)
# pulses: 60 s discharge at 2.7 A, 60 s rest, 60 s charge at 1.35 A, 60 s rest
PHASE = (T // 60) % 4
I = np.select([PHASE == 0, PHASE == 2], [-2.7, 1.35], 0.0)
SOC = 0.8 + np.concatenate([[0.0], np.cumsum(I[:-1])]) / 3600 / 2.7


def test_features_on_a_pulse_train() -> None:
    f = features(T, I, SOC)
    assert set(f) == {"time", "current", "abs_current", "direction", "dI_dt", "charge_passed", "since_rest", "soc"}
    assert f["direction"][0] == -1 and f["direction"][70] == 0 and f["direction"][130] == 1
    assert f["since_rest"][59] == pytest.approx(59.0) and f["since_rest"][60] == 0.0
    assert f["charge_passed"][-1] == pytest.approx((2.7 + 1.35) * 60 * 30 / 3600)


def test_white_noise_is_white_at_the_noise_level() -> None:
    rng = np.random.default_rng(0)
    v = 3.7 + 0.01 * I
    a = analyse(T, v + rng.normal(0, 1e-3, T.size), v, I, soc=SOC, noise_variance=1e-6)
    assert a.s2 == pytest.approx(1.0, rel=0.05)
    assert a.ljung_box_p > 0.01
    assert a.decorrelation_s <= 1.0
    assert a.slow_fraction < 0.05
    assert abs(a.bias) < 1e-4


def test_a_resistance_error_is_conditioned_on_current() -> None:
    rng = np.random.default_rng(1)
    v = 3.7 + 0.01 * I
    measured = v + 0.004 * I + rng.normal(0, 5e-4, T.size)  # 4 mΩ the model lacks
    a = analyse(T, measured, v, I, soc=SOC)
    top = a.summary()["features"][0]
    assert top["name"] in {"current", "direction"}
    assert a.by_feature["current"].correlation > 0.9
    assert a.ljung_box_p < 1e-6  # the error follows the pulses: not white


def test_a_drift_is_slow_and_correlated() -> None:
    v = 3.7 + 0.01 * I
    measured = v + 0.01 * (T / T[-1])  # 10 mV drift over two hours (e.g. lost capacity)
    a = analyse(T, measured, v, I, soc=SOC)
    assert a.slow_fraction > 0.9
    assert a.decorrelation_s > 600
    top = [f["name"] for f in a.summary()["features"][:3]]
    assert "time" in top or "charge_passed" in top


def test_nan_samples_are_left_out_and_all_nan_is_an_error() -> None:
    v = 3.7 + 0.01 * I
    sim = v.copy()
    sim[100:200] = np.nan
    a = analyse(T, v, sim, I)
    assert a.t.size == T.size - 100 and a.rmse == 0.0
    with pytest.raises(ValueError, match="no finite residual"):
        analyse(T, v, np.full_like(v, np.nan), I)


def test_figures_are_drawn(tmp_path) -> None:  # noqa: ANN001 (pytest tmp_path)
    from matplotlib.image import imread

    from battlab.diagnose.figures import conditional_errors, residual_vs_time, whiteness

    rng = np.random.default_rng(2)
    v = 3.7 + 0.01 * I
    a = analyse(T, v + 0.004 * I + rng.normal(0, 5e-4, T.size), v, I, soc=SOC)
    for draw, name in ((residual_vs_time, "time"), (conditional_errors, "features"), (whiteness, "white")):
        png = draw(a, tmp_path / f"{name}.png")
        img = imread(png)
        assert img.shape[0] > 200 and img.shape[1] > 400
        assert float(np.std(img[..., :3])) > 0.05  # not blank
