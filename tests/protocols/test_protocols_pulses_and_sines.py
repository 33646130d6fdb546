"""Pulse trains and sinusoids: structure, sampling and the L1 normalisation."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocols import Direction, InputError, PulseSpec, SineSpec, pulse_profile, sine_profile
from protocols.pulses import pulse_pieces


@settings(max_examples=80, deadline=None)
@given(
    width=st.sampled_from([1.0, 3.0, 10.0, 30.0, 100.0, 300.0, 1000.0]),
    n=st.integers(1, 3),
    total=st.sampled_from([600.0, 900.0, 1800.0, 3600.0]),
    direction=st.sampled_from(list(Direction)),
)
def test_pulse_train_structure(width: float, n: int, total: float, direction: Direction) -> None:
    spec = PulseSpec(width, n, total, direction)
    if spec.n_pulses < 1:
        with pytest.raises(InputError):
            pulse_profile(spec)
        return
    p = pulse_profile(spec)
    assert p.duration == total
    assert p.charge_throughput == pytest.approx(1.0, abs=1e-12)
    # every edge is a sample and no sample interval exceeds 1 s
    edges, _ = pulse_pieces(spec)
    assert np.isin(edges, p.t).all()
    assert np.diff(p.t).max() <= 1.0 + 1e-12
    amp = spec.amplitude_a()
    assert set(np.round(np.abs(p.current), 9)) <= {0.0, round(amp, 9)}
    d, c = p.segments()
    on = np.abs(c) > 0
    assert d[on].sum() == pytest.approx(spec.n_pulses * width)
    if direction is Direction.BOTH:
        assert p.net_charge == pytest.approx(0.0, abs=1e-12)
        assert c[on][0] < 0  # each bipolar pulse starts with its discharge half
    else:
        assert np.sign(p.net_charge) == direction.sign


def test_pulse_counts_and_trailing_rest() -> None:
    spec = PulseSpec(1000.0, 1, 3600.0, Direction.CHARGE)
    assert spec.n_pulses == 2  # pulses at 0 and 2000 s, rest from 3000 s
    d, c = pulse_profile(spec).segments()
    assert d.tolist() == [1000.0, 1000.0, 1000.0, 600.0]
    assert c[0] == pytest.approx(1.8) and c[1] == 0.0  # 1 Ah in 2000 s of on-time


def test_bipolar_one_second_pulses_are_sampled_at_half_seconds() -> None:
    p = pulse_profile(PulseSpec(1.0, 1, 600.0, Direction.BOTH))
    assert p.t[:4].tolist() == [0.0, 0.5, 1.0, 2.0]
    assert p.current[0] == -p.current[1]


@pytest.mark.parametrize("direction", list(Direction))
@pytest.mark.parametrize("f", [0.01, 0.05, 0.1])
def test_sines(direction: Direction, f: float) -> None:
    p = sine_profile(SineSpec(f, 600.0, direction))
    assert p.duration == 600.0
    assert np.diff(p.t).max() == 1.0
    assert p.charge_throughput == pytest.approx(1.0, abs=1e-12)
    per = round(1 / f)
    np.testing.assert_array_equal(p.current[:per], p.current[per : 2 * per])  # bit-identical periods
    if direction is Direction.BOTH:
        assert abs(p.net_charge) < 1e-12
    else:
        assert p.net_charge == pytest.approx(direction.sign * 1.0)
        assert np.all(direction.sign * p.current >= 0)


def test_sine_refuses_a_fraction_of_a_period() -> None:
    with pytest.raises(InputError, match="periods"):
        sine_profile(SineSpec(0.01, 650.0, Direction.BOTH))
