"""Equilibrium identification (eqs. 10-21): synthetic C/20 cycle on nca18650 and the real Panasonic C/20 test."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import battlab
from battlab.identify.equilibrium import fit_equilibrium, ocv_curve
from battlab.io import load_data
from protocols.errors import InputError
from tests.battlab.conftest import _c20_cycle


@pytest.fixture(scope="module")
def c20_cycle() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A simulated C/20 discharge, 1 h rest, C/20 charge on nca18650, sampled every 60 s."""
    return _c20_cycle()


def test_synthetic_c20_recovers_table4(c20_cycle) -> None:
    t, i, v = c20_cycle
    curve = ocv_curve(t, i, v, source="synthetic")
    assert "mean of charge and discharge" in curve.method
    cell = battlab.Cell.load("nca18650")
    eq = fit_equilibrium(curve, cell)
    assert eq.converged
    assert eq.rmse_5_95_mV < 5.0
    assert eq.eps_s_n == pytest.approx(0.5438895, rel=0.03)
    assert eq.eps_s_p == pytest.approx(0.6663649, rel=0.03)
    assert eq.n_Li == pytest.approx(0.1406, rel=0.03)
    assert eq.capacity == pytest.approx(cell.capacity(), rel=0.02)
    for soc, volt in eq.table5.items():  # Table 5 of the identified cell vs the true cell
        assert volt == pytest.approx(float(cell.ocv(soc)), abs=0.01)
    assert eq.cell["eps_s_n"] == eq.eps_s_n and eq.area_scale == 1.0


def test_discharge_only_is_shifted_and_bad_direction_is_an_error(c20_cycle) -> None:
    t, i, v = c20_cycle
    k = int(np.argmax(i > 0))
    curve = ocv_curve(t[:k], i[:k], v[:k])
    assert curve.method.startswith("single branch")
    eq = fit_equilibrium(curve, battlab.Cell.load("nca18650"))
    assert eq.capacity == pytest.approx(2.7, rel=0.03)
    with pytest.raises(InputError, match="expected θ⁻ to fall"):
        fit_equilibrium(ocv_curve(t[:k], -i[:k], v[:k]), battlab.Cell.load("nca18650"))


def test_panasonic_c20(shared_data) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = load_data(shared_data / "panasonic-18650pf" / "25degC_C20_OCV.mat")
    curve = ocv_curve(d.t, d.current, d.voltage, source=d.source)
    assert 30 < curve.half_gap_mV < 80  # C/20 overpotential + hysteresis, removed by the mean
    cell = battlab.Cell.load("nca18650")
    plain = fit_equilibrium(curve, cell, rated_capacity=2.9)  # the paper's method with the stand-in OCPs
    assert plain.rmse_5_95_mV < 25.0
    eq = fit_equilibrium(curve, cell, ocp_terms=6, rated_capacity=2.9)
    assert eq.rmse_5_95_mV <= 10.0  # the target, with the positive-OCP correction
    assert eq.rmse_5_95_mV < plain.rmse_5_95_mV
    for e in (plain, eq):
        assert 2.9 <= e.capacity <= 3.1  # 2.997 Ah were discharged at C/20
        assert e.cell["Q_nom"] == 2.9
        n0, n1, p0, p1 = e.window
        assert 0 <= n0 < n1 <= 1 and 0 <= p1 < p0 <= 1
        assert e.eps_s_n + e.cell["eps_e_n"] < 1 and e.eps_s_p + e.cell["eps_e_p"] < 1
    assert float(eq.cell.ocv(0.0)) == pytest.approx(2.5, abs=1e-6)
    assert float(eq.cell.ocv(1.0)) == pytest.approx(4.2, abs=1e-6)


def test_one_branch_of_a_full_cycle_is_that_branch_shifted_by_its_rest_step(c20_cycle) -> None:
    """branch="discharge" on a discharge-rest-charge cycle: the discharge alone, as if the charge were not logged
    (shifted up by its rest-step overpotential), not the mean of both; "charge" the same for the charge."""
    t, i, v = c20_cycle
    both = ocv_curve(t, i, v)
    dis = ocv_curve(t, i, v, branch="discharge")
    chg = ocv_curve(t, i, v, branch="charge")
    assert "single branch" in dis.method and "discharge only" in dis.method and "charge only" in chg.method
    k = int(np.argmax(i > 0))
    alone = ocv_curve(t[:k], i[:k], v[:k])
    q = np.linspace(0.2, 2.4, 12)
    assert np.interp(q, dis.q, dis.voltage) == pytest.approx(np.interp(q, alone.q, alone.voltage), abs=1e-3)
    assert np.max(np.abs(np.interp(q, dis.q, dis.voltage) - np.interp(q, both.q, both.voltage))) > 5e-3
    with pytest.raises(InputError, match="OCV branch 'rest'"):
        ocv_curve(t, i, v, branch="rest")
    with pytest.raises(InputError, match="no constant-current charge branch"):
        ocv_curve(t[:k], i[:k], v[:k], branch="charge")
