"""The virtual tester's DFN cell (battlab.lab.virtual over battlab.model.live.LiveCell): a step that does not
converge is retried in smaller pieces; a cell driven past its voltage limit holds at it; a step that fails all the
same leaves the cell as it was; a cell whose current sensor reads an offset is not drained through an open
circuit."""

from __future__ import annotations

import numpy as np
import pytest

from battlab.lab.virtual import make_cell_physics
from battlab.model.live import LiveCell


def test_a_step_that_fails_whole_is_retried_in_halves(monkeypatch: pytest.MonkeyPatch) -> None:
    reference = make_cell_physics("nca18650")
    reference.reset(0.5, 298.15)
    for _ in range(2):
        expected = reference.step(-5.4, 0.5, 298.15)
    physics = make_cell_physics("nca18650")
    physics.reset(0.5, 298.15)
    real = LiveCell._advance_once
    tried: list[float] = []

    def only_short_steps(self: LiveCell, I_dis: float, dt: float, *args: object) -> tuple[float, float, float]:
        tried.append(dt)
        if dt > 0.5:
            raise RuntimeError("cell model: step did not converge")
        return real(self, I_dis, dt, *args)

    monkeypatch.setattr(LiveCell, "_advance_once", only_short_steps)
    assert physics.step(-5.4, 1.0, 298.15) == pytest.approx(expected, abs=1e-12)  # the same two half steps
    assert tried == [1.0, 1.0, 1.0, 0.5, 0.5] and physics._live.t == 1.0


@pytest.mark.parametrize(("current", "dt", "soc0"), [(-0.9, 10.0, 0.03), (-0.135, 30.0, 0.04)])
def test_a_cell_whose_solution_ends_past_its_cut_off_holds_at_it_and_rests_from_there(
    current: float, dt: float, soc0: float
) -> None:
    """A cell whose negative electrode empties first (the window shifted, as the equilibrium cause's truth is), at C/3
    in 10 s steps and at C/20 in 30 s steps (the campaign's capacity check and OCV test): its voltage collapses through
    the 2.5 V cut-off within a second and its solution ends just past it, inside a step. The cell stops where the
    voltage reaches V_min (found inside the step), holds there under the same current (a cycler's limit catches it
    there), and rests from there (at C/20 the surface is then so near empty that the rest starts from where the held
    step began)."""
    from battlab.cell import Cell

    physics = make_cell_physics(Cell.load("nca18650-true+equilibrium:d_sto_n=0.008,d_sto_p=0.008,dU=0.003"))
    physics.reset(soc0, 298.15)
    live = physics._live
    v_min = float(live.cell["V_min"])
    for _ in range(200):
        v, _ = physics.step(current, dt, 298.15)
        if v <= v_min:
            break
    else:
        pytest.fail("the discharge did not reach V_min")
    assert v_min - 0.005 < v <= v_min  # stopped at the limit, not somewhere past it
    y, t = live._y.copy(), live.t
    assert physics.step(current, 5.0, 298.15)[0] == v and np.array_equal(live._y, y) and live.t == t + 5.0
    v_rest, _ = physics.step(0.0, 60.0, 298.15)
    assert v_rest > v_min + 0.1 and live.t == t + 65.0


def test_a_step_that_fails_in_every_piece_leaves_the_cell_as_it_was(monkeypatch: pytest.MonkeyPatch) -> None:
    """A step that does not converge however it is cut, with the voltage inside the cell's limits (no limit to stop
    at): it raises, the cell keeps its state from before that step, and rests from it."""
    physics = make_cell_physics("nca18650")
    physics.reset(0.5, 298.15)
    live = physics._live
    for _ in range(3):
        physics.step(-2.7, 1.0, 298.15)
    real = LiveCell._advance_once

    def no_charge(self: LiveCell, I_dis: float, *args: object) -> tuple[float, float, float]:
        if I_dis < 0:
            raise RuntimeError("cell model: step did not converge")
        return real(self, I_dis, *args)

    monkeypatch.setattr(LiveCell, "_advance_once", no_charge)
    y, t, v = live._y.copy(), live.t, live.voltage
    with pytest.raises(RuntimeError, match="did not converge"):
        physics.step(2.7, 1.0, 298.15)
    assert live.t == t and live.voltage == v and np.array_equal(live._y, y)
    v_rest, _ = physics.step(0.0, 10.0, 298.15)
    assert v_rest > v and live.t == t + 10.0


def test_an_offset_current_sensor_drains_the_cell_at_0_a_but_not_through_an_open_circuit() -> None:
    """The model's input is the logged current: at a 0 A setpoint a cycler whose sensor reads 15 mA too high drives
    15 mA out of the cell (the voltage falls), with its output off nothing flows and the cell rests."""
    from battlab.cell import Cell
    from drivers.virtual.instruments import SimulatedCycler
    from drivers.virtual.noise import NOISELESS
    from drivers.virtual.physics import ContactResistance

    cell = Cell.load("nca18650-true").with_extension("current_sensor", offset=0.015, gain=0.005)
    ends = {}
    for output, hidden in ((True, False), (False, False), (False, True)):
        physics = make_cell_physics(cell)
        physics = ContactResistance(physics, 0.005) if hidden else physics  # a hidden effect wraps the model
        c = SimulatedCycler(physics, noise=NOISELESS, rng=np.random.default_rng(0), max_step_s=300.0)
        c.reset_cell(0.5, 298.15)
        c.set_current(0.0)
        c.set_output(output)
        start = c.v_true
        c.advance(36000.0, 298.15)
        ends[output, hidden] = c.v_true - start
    assert ends[True, False] < -0.04  # 150 mAh out in 10 h: about 55 mV lower
    assert abs(ends[False, False]) < 1e-3  # the start carried the 15 mA (its ohmic drop, 0.7 mV), then nothing flows
    assert abs(ends[False, True]) < 1e-3  # also under a hidden effect's wrapper
