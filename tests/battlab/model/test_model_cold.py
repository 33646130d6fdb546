"""High currents at low temperatures: a run ends at the voltage cut-off (or the profile's end), never in a solver
failure, also where the electrolyte of an electrode empties and the voltage collapses."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import battlab
from protocols import Profile
from protocols.drive_cycles import Cycle, speed_trace
from protocols.ev_model import EVModel

DATA = Path(__file__).parent / "data"


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


def _us06_without_regen(q_nom: float, seconds: float) -> Profile:
    """The package's US06 through its EV model, scaled to a 3.5C largest discharge, charging clipped at 0 A."""
    trace = speed_trace(Cycle.US06)
    i = EVModel().cell_current(trace.t, trace.speed_mps, trace.grade)
    i = np.minimum(i * (3.5 * q_nom / float(-np.min(i))), 0.0)
    n = int(np.searchsorted(trace.t, seconds))
    return Profile(trace.t[: n + 1], np.concatenate([i[:n], i[n - 1 : n]]))


def test_a_current_jump_after_a_pivot_re_analysis_starts_from_its_right_limit() -> None:
    """The Panasonic fit (examples/panasonic/fit.sh, its kinetics falling fast with temperature: E_k_p = 85 kJ/mol)
    at -20 °C under US06 without regeneration meets a vanishing pivot on the first step after a 0.8C -> 2.8C jump at
    297 s, and the step is redone after a new pivot order. It must start from the right limit at the new current
    (kept in the step history), not from the state at the old current, from which Newton failed at every step size
    ("singular Jacobian"); from there the voltage collapses through the cut-off within the second."""
    cell = battlab.Cell.load(DATA / "panasonic_fit.bpx.json")
    prof = _us06_without_regen(float(cell["Q_nom"]), 320.0)
    res = battlab.simulate(cell, prof, soc0=1.0, ambient=253.15, v_limits=(2.0, 4.5))
    assert res.ended_by is not None and res.ended_by.startswith("V < 2"), res.ended_by
    assert res.t[-1] == 297.0


def test_the_edge_potential_is_negligible_inside_the_range_and_diverges_at_its_limits() -> None:
    """The ideal-solution term at the stoichiometry limits (battlab.model.dfn.edge_potential): below 0.2 mV
    further than 5 widths from a limit, raising the potential towards θ = 0 and lowering it towards θ = 1 by tens of
    mV at the limit, continued past it as its tangent (finite, monotone: a Newton iterate there is pushed back)."""
    import casadi as ca

    from battlab.model.dfn import EDGE_WIDTH, edge_potential

    x = ca.SX.sym("x")
    f = ca.Function("edge", [x], [edge_potential(x, 298.15)])
    inside = np.linspace(5 * EDGE_WIDTH, 1 - 5 * EDGE_WIDTH, 2001)
    assert np.max(np.abs(np.array(f(inside.reshape(1, -1))).ravel())) < 2e-4
    theta = np.array([-0.01, -1e-4, 0.0, 1e-4, EDGE_WIDTH, 3 * EDGE_WIDTH])
    low = np.array(f(theta.reshape(1, -1))).ravel()
    high = np.array(f((1.0 - theta).reshape(1, -1))).ravel()
    assert np.all(np.isfinite(low)) and np.all(np.diff(low) < 0) and low[2] > 0.05
    assert np.allclose(high, -low)


def test_a_surface_that_filled_during_the_step_before_a_current_change_is_the_run_s_end() -> None:
    """No right limit at a current change, the voltage still inside the limits, but the state before the change has
    a particle surface past full (the fitted Panasonic cell on WLTC 3b at -10 °C, its discharge easing from 8.59 to
    8.36 A while the voltage collapses: 2.03 V, θ⁺ 1.0000054 at the left limit). That is the end check_end gives at a
    sample, not a solver failure; with every surface inside its range it stays a solver failure."""
    from battlab.model.solver import _no_right_limit

    limits = {"V_min": 2.0, "V_max": 4.5, "T_max": 333.15}
    why = _no_right_limit(5170.0, 8.5885, 8.3617, limits, 2.029, (0.022, 1.0000054))
    assert why.startswith("surface stoichiometry reached 1"), why
    assert _no_right_limit(5170.0, 8.5885, 8.3617, limits, 2.029, (0.022, 0.99)).startswith("solver:")
