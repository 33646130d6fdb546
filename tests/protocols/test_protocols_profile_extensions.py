"""Profile additions: segments, SOC, zero-order-hold evaluation, metadata copies."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from protocols import InputError, Profile


def test_segments_merge_equal_neighbours_and_drop_the_last_sample() -> None:
    p = Profile(np.arange(6.0), [1.0, 1.0, 0.0, 2.0, 2.0, 7.0])
    d, c = p.segments()
    assert d.tolist() == [2.0, 1.0, 2.0]
    assert c.tolist() == [1.0, 0.0, 2.0]


def test_soc_counts_charge_from_the_start_soc() -> None:
    p = Profile([0.0, 3600.0], [2.7, 2.7], soc0=0.25)
    assert p.soc(2.7).tolist() == pytest.approx([0.25, 1.25])
    assert p.soc(2.7, soc0=0.0)[-1] == pytest.approx(1.0)
    with pytest.raises(InputError):
        p.soc(0.0)


def test_value_at_is_the_right_limit_of_the_hold() -> None:
    p = Profile([0.0, 1.0, 3.0], [5.0, -1.0, 0.0])
    assert p.value_at([0.0, 0.99, 1.0, 2.5, 3.0, 10.0]).tolist() == [5.0, 5.0, -1.0, -1.0, 0.0, 0.0]


def test_with_meta_replaces_fields_and_refuses_unknown_ones() -> None:
    p = Profile([0.0, 1.0], [1.0, 1.0], id=3, kind="pulse", soc0=0.4, params={"a": 1})
    q = p.with_meta(id=4)
    assert (q.id, q.kind, q.soc0, dict(q.params)) == (4, "pulse", 0.4, {"a": 1})
    with pytest.raises(InputError, match="unknown profile field"):
        p.with_meta(colour="red")


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 50), st.sampled_from([-3.0, -1.5, 0.0, 0.5, 2.0])), min_size=1, max_size=40))
def test_from_segments_inverts_segments(pieces: list[tuple[int, float]]) -> None:
    d = np.array([x[0] * 0.5 for x in pieces])
    c = np.array([x[1] for x in pieces])
    p = Profile.from_segments(d, c)
    assert p.duration == pytest.approx(d.sum())
    assert p.charge_throughput == pytest.approx(float(np.sum(np.abs(c) * d)) / 3600)
    d2, c2 = p.segments()
    q = Profile.from_segments(d2, c2)
    grid = np.linspace(0, p.duration, 97, endpoint=False)
    np.testing.assert_array_equal(p.value_at(grid), q.value_at(grid))
    assert np.all(np.diff(c2) != 0)
