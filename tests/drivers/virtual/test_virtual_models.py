"""The virtual tester's models without sockets: stand-in physics, noise, simulated cycler and chamber."""

from __future__ import annotations

import math

import numpy as np
import pytest

from drivers.virtual.instruments import (
    INH,
    LIM_POS,
    MODEL,
    OT,
    PROT,
    VLIM_NEG,
    WDOG,
    ChamberConfig,
    ExecutionError,
    SimulatedChamber,
    SimulatedCycler,
)
from drivers.virtual.noise import NOISELESS, NoiseModel
from drivers.virtual.physics import (
    CellLimits,
    CellPhysics,
    ContactResistance,
    EquivalentCircuitCell,
    apply_effects,
    nca_ocv,
)


def test_standin_is_a_cell_physics() -> None:
    assert isinstance(EquivalentCircuitCell(), CellPhysics)
    assert isinstance(ContactResistance(EquivalentCircuitCell(), 0.01), CellPhysics)


def test_ocv_is_monotone_over_the_window() -> None:
    socs = np.linspace(0, 1, 201)
    ocv = np.array([nca_ocv(s) for s in socs])
    assert np.all(np.diff(ocv) > 0) and 2.5 < ocv[0] < 2.8 and 4.1 < ocv[-1] < 4.2


def test_positive_current_charges() -> None:
    cell = EquivalentCircuitCell()
    cell.reset(0.5, 298.15)
    v0 = cell.voltage
    v, _ = cell.step(2.7, 60.0, 298.15)
    assert v > v0 + 2.7 * cell.params.R0_ohm * 0.9  # ohmic rise plus charge
    assert cell.soc == pytest.approx(0.5 + 2.7 * 60 / 3600 / 2.7)
    cell.reset(0.5, 298.15)
    v, _ = cell.step(-2.7, 60.0, 298.15)
    assert v < v0 and cell.soc < 0.5


@pytest.mark.parametrize("current", [5.4, -5.4])
def test_joule_heating_in_both_directions(current: float) -> None:
    cell = EquivalentCircuitCell()
    cell.reset(0.5, 298.15)
    T = 298.15
    for _ in range(300):
        _, T = cell.step(current, 1.0, 298.15)
    assert T > 298.15 + 0.2


def test_thermal_relaxation_to_ambient() -> None:
    cell = EquivalentCircuitCell()
    cell.reset(0.5, 298.15)
    tau = cell.params.heat_capacity_J_K / cell.params.hA_W_K
    _, surface = cell.step(0.0, tau, 308.15)
    assert surface == pytest.approx(308.15 - 10 * math.exp(-1), abs=1e-9)


def test_contact_resistance_hidden_effect() -> None:
    plain, wrapped = (
        EquivalentCircuitCell(),
        apply_effects(EquivalentCircuitCell(), [lambda p: ContactResistance(p, 0.05)]),
    )
    for cell in (plain, wrapped):
        cell.reset(0.5, 298.15)
    v1, _ = plain.step(2.0, 10.0, 298.15)
    v2, _ = wrapped.step(2.0, 10.0, 298.15)
    assert v2 - v1 == pytest.approx(0.1)
    assert wrapped.voltage - plain.voltage == pytest.approx(0.1)


def test_noise_is_physical() -> None:
    rng = np.random.default_rng(1)
    model = NoiseModel()
    readings = np.array([model.voltage(3.7, 0.0, 0.0, rng) for _ in range(4000)])
    steps = readings / 100e-6
    assert np.allclose(steps, np.round(steps), atol=1e-6)  # 100 µV quantisation
    quiet = np.std(readings)
    loud = np.std([model.voltage(3.7, 10.0, 0.0, rng) for _ in range(4000)])
    slewing = np.std([model.voltage(3.7, 0.0, 0.5, rng) for _ in range(4000)])
    assert loud > 2 * quiet  # current-dependent component
    assert slewing == pytest.approx(0.5 * model.sample_jitter_s, rel=0.1)  # jitter × dV/dt dominates
    assert NOISELESS.voltage(3.71234567, 5.0, 1.0, rng) == 3.71234567


def test_a_reading_just_after_a_current_step_is_not_blown_up_by_the_jitter() -> None:
    """A sample 0.1 ms after a 2.7 A step: the slope over that instant is the whole 81 mV jump divided by 0.1 ms; a
    2 ms jitter reads at most the voltage before the step, not volts beyond it (seen at 1x: 4.29 V read at 3.44 V)."""
    cell = EquivalentCircuitCell()
    c = SimulatedCycler(cell, noise=NoiseModel(), rng=np.random.default_rng(3), max_step_s=1.0)
    c.reset_cell(0.5, 298.15)
    c.advance(10.0, 298.15)
    before = c.v_true
    c.set_current(-2.7)
    c.set_output(True)
    c.advance(10.0001, 298.15)
    jump = before - c.v_true
    assert 0.07 < jump < 0.1
    readings = np.array([c.measure_voltage() for _ in range(2000)])
    assert np.all(readings <= before + 1e-3) and np.all(readings >= c.v_true - jump - 1e-3)


def make_cycler(**kw: object) -> SimulatedCycler:
    cell = EquivalentCircuitCell()
    c = SimulatedCycler(cell, noise=NOISELESS, rng=np.random.default_rng(0), max_step_s=1.0)
    c.reset_cell(float(kw.pop("soc0", 0.5)), 298.15)  # type: ignore[arg-type]
    for k, v in kw.items():
        setattr(c, k, v)
    return c


def test_watchdog_trips_at_its_deadline_even_with_one_coarse_advance() -> None:
    c = make_cycler(watchdog_enabled=True, watchdog_delay_s=5)
    c.set_current(1.0)
    c.set_output(True)
    c.note_io(2.0)
    c.advance(100.0, 298.15)  # one call far past the deadline (a host that died)
    assert not c.output_on and c.status >> WDOG & 1 and c.status >> PROT & 1
    assert c.trips[-1].t_s == pytest.approx(7.0)  # last I/O + delay, exactly
    assert c.i_true == 0.0


def test_voltage_limits_trip_on_charge_and_discharge() -> None:
    c = make_cycler(soc0=0.95, voltage_limit=4.1)
    c.set_current(2.7)
    c.set_output(True)
    c.advance(3600.0, 298.15)
    assert c.status >> LIM_POS & 1 and c.trips[0].t_s <= 1.0 and "4.1 V" in c.trips[0].reason
    assert c.v_true < 4.1 and c.i_true == 0.0  # relaxing at rest after the trip
    with pytest.raises(ExecutionError, match="protection latched"):
        c.set_output(True)
    c.clear_protection()
    c.set_current(-5.4)
    c.set_output(True)
    c.advance(10000.0, 298.15)
    assert c.status >> VLIM_NEG & 1 and 1.0 < c.trips[-1].t_s < 10000.0


def test_over_temperature_and_interlock() -> None:
    c = make_cycler()
    c.set_output(True)
    c.forced_T_K = 400.0
    c.advance(1.0, 298.15)
    assert c.status >> OT & 1 and not c.output_on
    c2 = make_cycler()
    c2.set_output(True)
    c2.inhibit("chamber alarm")
    assert c2.status >> INH & 1 and not c2.output_on


def test_current_beyond_programmed_limits_is_refused() -> None:
    c = make_cycler(current_limit=2.0)
    with pytest.raises(ExecutionError) as info:
        c.set_current(2.5)
    assert info.value.code == -222


class ExplodingCell(EquivalentCircuitCell):
    def step(self, current_A: float, dt_s: float, ambient_K: float) -> tuple[float, float]:
        if current_A:
            raise RuntimeError("solver diverged")
        return super().step(current_A, dt_s, ambient_K)


def test_a_failing_model_turns_the_output_off() -> None:
    c = SimulatedCycler(ExplodingCell(), noise=NOISELESS, rng=np.random.default_rng(0))
    c.reset_cell(0.5, 298.15)
    c.set_current(1.0)
    c.set_output(True)
    c.advance(5.0, 298.15)
    assert c.status >> MODEL & 1 and not c.output_on and c.pop_error()[0] == -310
    c.advance(10.0, 298.15)  # time goes on
    assert c.t == 10.0
    with pytest.raises(ExecutionError):
        c.set_output(True)
    c.clear_protection()  # the next run's reset: the cell goes on from its last good state
    c.set_current(0.0)
    c.set_output(True)
    c.advance(15.0, 298.15)
    assert c.output_on and not c.tripped and c.physics_steps > 0


def test_error_queue_overflow() -> None:
    c = make_cycler()
    for _ in range(40):
        c.push_error(-113, "Undefined header")
    assert len(c.errors) == 30 and c.errors[-1] == (-350, "Queue overflow")


def test_chamber_first_order_air() -> None:
    ch = SimulatedChamber(ChamberConfig(tau_s=200.0, T0_K=298.15), rng=np.random.default_rng(0))
    ch.set_point_C(45.0)
    ch.advance(200.0)
    assert ch.T_air_K == pytest.approx(318.15 - 20.0 * math.exp(-1.0))
    ch.trigger_alarm(3)
    ch.advance(10_000.0)
    assert ch.T_air_K == pytest.approx(ch.config.room_K, abs=1e-6)  # an alarm stops control
    with pytest.raises(ExecutionError):
        ch.set_point_C(500.0)


def test_limits_dataclass_defaults() -> None:
    assert CellLimits().v_max_V == 4.2
