"""High currents at low temperatures: a run ends at the voltage cut-off (or the profile's end), never in a solver
failure, also where the electrolyte of an electrode empties and the voltage collapses."""

from __future__ import annotations

import numpy as np
import pytest

import battlab
from protocols import Profile


@pytest.fixture(scope="module")
def cell() -> battlab.Cell:
    return battlab.Cell.load("nca18650")


@pytest.mark.parametrize("c_rate", [2.0, 3.0, 4.0])
def test_a_high_rate_discharge_at_minus_20_degc_ends_at_the_cut_off(cell: battlab.Cell, c_rate: float) -> None:
    """From full charge at -20 °C the positive electrode's electrolyte empties within a minute at 2-4C and the
    voltage collapses through 2.0 V between two 1 s samples; the step after it has no solution. That is the cut-off
    (a tester stops there), not a solver failure; the samples before it are kept."""
    t = np.arange(0.0, 301.0)
    prof = Profile(t, np.full(t.size, -c_rate * float(cell["Q_nom"])))
    res = battlab.simulate(cell, prof, soc0=1.0, ambient=253.15, v_limits=(2.0, 4.5))
    assert res.ended_by is not None and res.ended_by.startswith("V < 2"), res.ended_by
    assert 10 < res.t[-1] < 100
    assert np.all(res.voltage >= 2.0)
