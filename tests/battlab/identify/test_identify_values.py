"""Fit of cell values outside the 18 (contact resistance, heat transfer) by finite differences."""

from __future__ import annotations

import numpy as np
import pytest

import battlab
from battlab.identify.values import Trace, fit_values, parse_names, parse_value_stage
from protocols.errors import InputError
from protocols.profile import Profile


def _trace(cell: battlab.Cell, name: str = "pulses") -> Trace:
    """2C discharge pulses with rests (1 s samples, 30 min) simulated with ``cell`` at 25 degC from SOC 0.9."""
    t = np.arange(0.0, 1800.0, 1.0)
    i = np.where((t % 300.0) < 120.0, -5.4, 0.0)
    prof = Profile(t, i, id=name)
    res = battlab.simulate(cell, prof, soc0=0.9, ambient=298.15)
    return Trace(name, prof, 0.9, 298.15, None, res.voltage, res.T_surface)


@pytest.mark.slow
def test_fit_values_recovers_the_heat_transfer_from_the_surface_temperature() -> None:
    """Each value tried is a new compiled model (about 30 s): one parameter, few evaluations."""
    cell = battlab.Cell.load("nca18650")
    truth = cell.with_values(h2a=2.0 * float(cell["h2a"]))
    vf = fit_values(cell, [_trace(truth)], ("h2a",), target="temperature", max_nfev=4)
    assert vf.values["h2a"] == pytest.approx(float(truth["h2a"]), rel=0.1)
    assert vf.rmse_after["pulses"] < 0.5 * vf.rmse_before["pulses"]
    assert vf.cell["h2a"] == vf.values["h2a"] and vf.start["h2a"] == float(cell["h2a"])


def test_bad_value_names_and_targets_are_one_clear_error() -> None:
    cell = battlab.Cell.load("nca18650")
    with pytest.raises(InputError, match="'R_x'.*not a parameter of cell"):
        parse_names("R_c,R_x", cell)
    with pytest.raises(InputError, match="'U_p'.*not a positive number"):
        parse_names("U_p", cell)
    with pytest.raises(InputError, match="named twice"):
        parse_names("R_c,R_c", cell)
    with pytest.raises(InputError, match="target 'heat'"):
        parse_value_stage("heat:R_c")
    assert parse_value_stage("R_c,E_kappa") == ("voltage", "R_c,E_kappa")
    assert parse_value_stage("temperature:C1+C2,h2a") == ("temperature", "C1+C2,h2a")
