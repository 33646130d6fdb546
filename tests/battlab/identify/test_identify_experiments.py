"""Logged data → fit experiments: the ambient is measured or given, never guessed."""

from __future__ import annotations

from pathlib import Path

import pytest

from battlab import Cell, InputError
from battlab.identify.experiments import experiments_from_data
from battlab.io.data import load_data


def test_panasonic_cold_tests_without_a_chamber_reading_need_the_ambient(shared_data: Path) -> None:
    """The 0 °C HWFET file has an empty chamber column: refused with the reason, or taken at the given value."""
    data = load_data(shared_data / "panasonic-18650pf" / "0degC_HWFET.mat")
    cell = Cell.load("nca18650").with_values(Q_nom=2.9)
    with pytest.raises(InputError, match=r"0degC_HWFET\.mat: no ambient temperature logged \(column 'Ambient"):
        experiments_from_data(data, cell, soc0=0.9)
    exps = experiments_from_data(data, cell, soc0=0.9, ambient=273.15)
    assert exps and all(e.ambient == 273.15 for e in exps)
    with pytest.raises(InputError, match="not a temperature in kelvin"):
        experiments_from_data(data, cell, soc0=0.9, ambient=0.0)
