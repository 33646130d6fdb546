"""The measurement-variance model (eqs. 36-40): refitting it from few repeated runs, and its file."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from battlab.noise import NoiseModel, load, save
from protocols.errors import InputError
from protocols.profile import Profile


def _trials(q: float, n: int = 600, trials: int = 3, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return 3.7 + q * rng.standard_normal((trials, n))


def _pulse(amps: float, n: int = 600) -> Profile:
    t = np.arange(n + 1, dtype=float)
    return Profile(t, np.full(n + 1, amps))


def test_one_run_per_direction_gives_its_measured_level_not_the_papers() -> None:
    """With one charge-only and one discharge-only run (the paper's fit needs two per direction) each direction
    gets its measured q: the paper's coefficients predict 2-30 mV for another tester."""
    runs = [(_pulse(2.7), _trials(1e-4, seed=1)), (_pulse(-5.4), _trials(2e-4, seed=2))]
    m = NoiseModel.fit(runs, floor=1e-5)
    assert m.q(_pulse(2.7)) == pytest.approx(1e-4, rel=0.1)
    assert m.q(_pulse(-5.4)) == pytest.approx(2e-4, rel=0.1)
    assert m.q(_pulse(-1.0)) == pytest.approx(2e-4, rel=0.1)  # a constant: one run has no slope
    mixed = Profile(np.arange(601.0), np.where(np.arange(601) % 2, 2.7, -5.4))
    assert m.q(mixed) == pytest.approx(1.5e-4, rel=0.1)  # eq. 39: the mean
    assert NoiseModel().q(_pulse(-5.4)) > 5 * m.q(_pulse(-5.4))


def test_mixed_runs_alone_give_a_constant_level() -> None:
    mixed = Profile(np.arange(601.0), np.where(np.arange(601) % 2, 2.7, -2.7))
    m = NoiseModel.fit([(mixed, _trials(1.2e-4))], floor=1e-5)
    for p in (_pulse(1.0), _pulse(-8.0), mixed):
        assert m.q(p) == pytest.approx(1.2e-4, rel=0.1)
    assert NoiseModel.fit([]) == NoiseModel()  # nothing measured: the paper's


def test_a_noise_model_file_round_trips_and_reads_the_campaigns(tmp_path: Path) -> None:
    m = NoiseModel(1e-6, 1e-4, 1.1e-4, 1e-3, 5e-5)
    assert load(save(m, tmp_path / "noise.toml", source="test")) == m
    (tmp_path / "noise.json").write_text(json.dumps({"model": m.to_dict(), "runs": [], "repeats": 3}))
    assert load(tmp_path / "noise.json") == m


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("[model]\na_c = 1.0\n", "missing ['b_c', 'a_d', 'b_d']"),
        ("[model]\na_c = 1\nb_c = 0\na_d = 1\nb_d = 0\nq = 2\n", "unknown ['q']"),
        ("[model]\na_c = 'x'\nb_c = 0\na_d = 1\nb_d = 0\n", "model.a_c must be a finite number"),
        ("[model]\na_c = 1\nb_c = 0\na_d = 1\nb_d = 0\nfloor = 0\n", "model.floor must be positive"),
        ("a_c = 1\n", "expected a 'model' table"),
        ("[model\n", "not a noise model file"),
    ],
)
def test_a_bad_noise_file_is_one_line_naming_the_file_and_field(tmp_path: Path, text: str, expected: str) -> None:
    path = tmp_path / "noise.toml"
    path.write_text(text)
    with pytest.raises(InputError, match="noise.toml") as err:
        load(path)
    assert expected in str(err.value) and "\n" not in str(err.value)
    with pytest.raises(InputError, match="cannot read"):
        load(tmp_path / "missing.toml")


def test_repeat_noise_is_the_white_noise_not_the_trials_different_start_states() -> None:
    """Trials that start from slightly different states differ by smooth curves (an offset, a relaxation) far
    larger than the noise; eq. 36's q is the noise's level all the same."""
    from battlab.noise import repeat_noise

    t = np.arange(900.0)
    base = 3.7 - 0.1 * np.sin(t / 40.0)
    rng = np.random.default_rng(3)
    drift = [2e-3 * k * (1 + np.exp(-t / 300.0)) for k in (-1, 0, 1, 2)]
    v = np.stack([base + d + 120e-6 * rng.standard_normal(t.size) for d in drift])
    assert repeat_noise(v) == pytest.approx(120e-6, rel=0.05)
    assert float(np.sqrt(np.mean(np.var(v, axis=0, ddof=1)))) > 10 * 120e-6  # eq. 36 on the trials as they are
    with pytest.raises(InputError, match="n_trials"):
        repeat_noise(v[:1])


def test_a_logged_pulse_train_keeps_its_direction_through_the_current_sensors_noise() -> None:
    """The rests of a logged discharge pulse train read the current sensor's noise (both signs, below a mA): the
    profile is still discharge-only, and its trials fit the discharge curve."""
    from battlab.noise import Direction, direction

    rng = np.random.default_rng(0)
    i = np.where(np.arange(601) % 60 < 10, -5.4, 0.0) + 2e-4 * rng.standard_normal(601)
    logged = Profile(np.arange(601.0), i)
    assert direction(logged) is Direction.DISCHARGE
    m = NoiseModel.fit([(logged, _trials(2e-4)), (_pulse(2.7), _trials(1e-4, seed=4))], floor=1e-5)
    assert m.q_discharge(1.0) == pytest.approx(2e-4, rel=0.1) and m.q_charge(1.0) == pytest.approx(1e-4, rel=0.1)
