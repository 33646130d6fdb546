"""The virtual tester's DFN cell (battlab.lab.virtual over battlab.model.live.LiveCell): a step that does not
converge is retried in smaller pieces; one that fails all the same leaves the cell as it was; a cell whose current
sensor reads an offset is not drained through an open circuit."""

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


def test_a_step_that_fails_in_every_piece_leaves_the_cell_as_it_was() -> None:
    """20 A charge from 95 % SOC: after about 24 s the DFN does not converge however the step is cut (the failure
    comes part-way through a step); the cell keeps its state from before that step, and rests from it."""
    physics = make_cell_physics("nca18650")
    physics.reset(0.95, 298.15)
    live = physics._live
    for _ in range(60):
        y, t, v = live._y.copy(), live.t, live.voltage
        try:
            physics.step(20.0, 1.0, 298.15)
        except RuntimeError as exc:
            assert "did not converge" in str(exc)
            break
    else:
        pytest.fail("20 A from 95 % SOC did not fail")
    assert live.t == t and live.voltage == v and np.array_equal(live._y, y)
    v_rest, _ = physics.step(0.0, 10.0, 298.15)
    assert v_rest < v and live.t == t + 10.0


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
