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


def _stepped_log(first: str) -> object:
    """A run log's shape: step 1 a charge tapering at 4.2 V ("cccv") or a 100 s discharge at 1 A ("rest"), step 2
    a rest (600 s at 4.19 V, or 1 h at the OCV of SOC 0.6), step 3 a 300 s discharge at 1 A; and the number of
    samples before the start state is known (after step 1, or after the long rest)."""
    import numpy as np

    from battlab.io.data import AMBIENT, CURRENT, STEP, TIME, VOLTAGE, LoggedData

    cell = Cell.load("nca18650")
    if first == "cccv":
        i1 = np.r_[np.full(100, 1.35), np.linspace(1.35, 0.03, 100)]
        v1 = np.r_[np.linspace(3.9, 4.2, 100), np.full(100, 4.2)]
        n_rest, v_rest = 600, 4.19
    else:
        i1, v1 = np.full(100, -1.0), np.linspace(3.8, 3.7, 100)
        n_rest, v_rest = 3600, float(cell.ocv(0.6))
    i = np.r_[i1, np.zeros(n_rest), np.full(300, -1.0)]
    v = np.r_[v1, np.full(n_rest, v_rest), np.linspace(v_rest - 0.1, v_rest - 0.2, 300)]
    step = np.r_[np.ones(i1.size), np.full(n_rest, 2.0), np.full(300, 3.0)]
    t = np.arange(i.size, dtype=float)
    cols = {TIME: t, VOLTAGE: v, CURRENT: i, AMBIENT: np.full(t.size, 25.0), STEP: step}
    return LoggedData("run", cols, {"soc0": None}), i1.size + (0 if first == "cccv" else n_rest)


@pytest.mark.parametrize(("first", "soc0"), [("cccv", 1.0), ("rest", 0.6)])
def test_a_run_log_starts_from_its_logged_charge_or_rest(first: str, soc0: float) -> None:
    """A run log begins with the plan's CCCV (current flows at its first sample): the start state is the end of
    that charge (SOC 1), or of a long rest (the SOC of its last voltage), not an error asking for --soc0."""
    data, n_first = _stepped_log(first)
    (e,) = experiments_from_data(data, Cell.load("nca18650"))
    assert e.soc0 == pytest.approx(soc0, abs=1e-6)
    assert e.voltage.size == len(data) - n_first  # from the first sample after that step
    assert e.voltage[0] == pytest.approx(data.voltage[n_first])


def test_a_log_without_a_state_setting_step_still_needs_the_start_soc() -> None:
    import numpy as np

    from battlab.io.data import CURRENT, STEP, LoggedData

    data, _ = _stepped_log("cccv")
    cols = dict(data.columns)
    cols[CURRENT] = np.where(cols[STEP] == 1, 1.35, cols[CURRENT])  # no taper: the charge did not end full
    with pytest.raises(InputError, match="give the start SOC"):
        experiments_from_data(LoggedData("run", cols, {}), Cell.load("nca18650"))
