"""The virtual tester over real loopback sockets: SCPI over TCP, Modbus TCP, Modbus RTU over a socket link,
the Espec text protocol; clock, watchdog, interlocks, hidden effects, served dialects."""

from __future__ import annotations

import math
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from drivers import Measurement, open_instruments
from drivers.chambers.espec import EspecP300
from drivers.chambers.watlow_f4t import WatlowF4T
from drivers.clock import RealClock, TrackedClock
from drivers.errors import InstrumentFault
from drivers.scpi.cycler import ScpiCycler
from drivers.scpi.dialects import KEYSIGHT_N7900
from drivers.testing import wait_until
from drivers.transport import LineAdapter
from drivers.virtual.faults import DeviceFaultPlan
from drivers.virtual.instruments import ChamberConfig
from drivers.virtual.lab import VirtualLab, VirtualLabConfig
from drivers.virtual.noise import NOISELESS
from drivers.virtual.physics import CellLimits, ContactResistance, EquivalentCircuitCell
from protocols.errors import InputError


def test_scpi_charge_session(make_lab) -> None:  # noqa: ANN001
    lab = make_lab(noise=NOISELESS)
    cyc = ScpiCycler.open(lab.cycler_url)
    assert cyc.identify() == "battlab,Virtual Cycler VC-1,SIM0001,0.1"
    cyc.initialize()
    cyc.set_voltage_limits(2.5, 4.2)
    cyc.set_current_limits(5.4, 13.5)
    soc0 = lab.physics.soc
    cyc.set_current(2.7)  # positive = charge
    cyc.output(True)
    first = cyc.measure()
    assert wait_until(lambda: lab.clock.now() > first.t_s + 60, 2.0)
    later = cyc.measure()
    assert later.t_s > first.t_s + 60 and later.voltage_V > first.voltage_V
    assert later.current_A == pytest.approx(2.7) and lab.physics.soc > soc0
    assert later.temperature_K == pytest.approx(lab.cycler.T_cell_K, abs=0.05)
    cyc.set_current(-2.7)
    m = cyc.measure()
    assert m.current_A == pytest.approx(-2.7) and lab.snapshot()["current_A"] == -2.7
    cyc.output(False)
    assert cyc.measure().current_A == 0.0 and not cyc.protection().tripped
    cyc.close()


def test_measurements_are_quantised_and_noisy(make_lab) -> None:  # noqa: ANN001
    lab = make_lab()
    cyc = ScpiCycler.open(lab.cycler_url)
    volts = np.array([cyc.measure().voltage_V for _ in range(300)])
    assert np.allclose(volts / 1e-4, np.round(volts / 1e-4), atol=1e-6)
    assert 20e-6 < volts.std() < 200e-6  # white noise at rest, plus relaxation
    cyc.close()


def test_error_queue_over_the_wire(make_lab) -> None:  # noqa: ANN001
    lab = make_lab()
    cyc = ScpiCycler.open(lab.cycler_url)
    cyc.adapter.write("BOGUS:CMD 1")
    cyc.adapter.write("CURR 99")
    cyc.adapter.write("CURR:LIM 1")
    cyc.adapter.write("CURR 1.5")  # beyond the programmed current limit
    assert cyc.errors() == [
        (-113, "Undefined header"),
        (-222, "Data out of range"),
        (-222, "Data out of range; beyond CURR:LIM"),
    ]
    with pytest.raises(InstrumentFault, match="'OUTP 1' rejected"):
        lab.cycler.status = 1 << 11  # latched protection: the output cannot be enabled
        cyc.output(True)
    cyc.close()


def test_watchdog_turns_output_off_within_one_virtual_second(make_lab) -> None:  # noqa: ANN001
    lab = make_lab(speed=1000.0)
    cyc = ScpiCycler.open(lab.cycler_url)
    cyc.set_watchdog(5)
    cyc.set_current(1.0)
    cyc.output(True)
    last_io = lab.cycler.last_io_t
    assert wait_until(lambda: lab.snapshot()["t_s"] > last_io + 20, 2.0)  # the host stays silent
    state = cyc.protection()
    assert state.tripped and {"WDOG", "PROT"} <= state.causes
    trip = lab.cycler.trips[-1]
    assert 0.0 <= trip.t_s - (last_io + 5.0) <= 1.0
    assert cyc.measure().current_A == pytest.approx(0.0, abs=2e-3)
    cyc.clear_protection()
    assert not cyc.protection().tripped and not lab.cycler.output_on  # clearing never re-enables
    cyc.close()


def test_killed_host_does_not_freeze_the_virtual_clock(make_lab) -> None:  # noqa: ANN001
    lab = make_lab(speed=1000.0)
    script = textwrap.dedent(f"""
        import time
        from drivers.scpi.cycler import ScpiCycler
        c = ScpiCycler.open({lab.cycler_url!r})
        c.set_watchdog(10); c.set_current(2.0); c.output(True)
        print("on", flush=True)
        time.sleep(60)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None and proc.stdout.readline().strip() == "on"
        assert lab.snapshot()["output_on"]
        proc.kill()  # kill -9: no goodbye, the socket just dies
        proc.wait(5)
        t_killed = lab.snapshot()["t_s"]
        assert wait_until(lambda: lab.snapshot()["t_s"] > t_killed + 30, 2.0)  # time goes on by itself
        assert wait_until(lambda: not lab.snapshot()["output_on"], 2.0)
        trip = lab.cycler.trips[-1]
        assert "watchdog" in trip.reason and trip.t_s - (lab.cycler.last_io_t + 10) <= 1.0
    finally:
        if proc.poll() is None:
            proc.kill()


def test_f4t_over_modbus_tcp_first_order_air(make_lab) -> None:  # noqa: ANN001
    lab = make_lab(chamber=ChamberConfig(tau_s=100.0, T0_K=298.15, reading_noise_K=0.0))
    ch = WatlowF4T.open(lab.chamber_url)
    assert ch.identify() == "Watlow F4T F4T1L1AA1A2AAAA"
    assert ch.read() == pytest.approx(25.0, abs=0.05)
    with lab.lock:
        t0 = lab.advance()
        lab.chamber.sp_K = 45.0 + 273.15  # the same step the driver makes, at a known virtual time

    def model(t: float) -> float:
        return 45.0 - 20.0 * math.exp(-(t - t0) / 100.0)

    for _ in range(20):  # the reading lies on the first-order curve between the times bracketing the read
        t_before = lab.clock.now()
        reading = ch.read()
        t_after = lab.clock.now()
        assert model(t_before) - 0.05 <= reading <= model(t_after) + 0.05
        time.sleep(0.02)
    ch.set_point(30.0)
    assert lab.chamber.sp_K == pytest.approx(303.15)
    with pytest.raises(InputError, match="outside the loop range"):
        ch.set_point(200.0)
    ch.close()


def test_wait_stable_on_the_instruments_clock(make_lab) -> None:  # noqa: ANN001
    lab = make_lab(chamber=ChamberConfig(tau_s=60.0))
    cyc = ScpiCycler.open(lab.cycler_url)
    clock = cyc.clock()
    assert isinstance(clock, TrackedClock) and clock.speed == 1000.0
    before, estimate, after = lab.clock.now(), clock.now(), lab.clock.now()
    assert before - 1.0 - clock.uncertainty_s <= estimate <= after + 1.0 + clock.uncertainty_s
    ch = WatlowF4T.open(lab.chamber_url)
    ch.set_point(35.0)
    t0 = clock.now()
    T = ch.wait_stable(0.5, 3600.0, clock, hold_s=60.0, poll_s=10.0)
    assert abs(T - 35.0) <= 0.5 and 100.0 < clock.now() - t0 < 1000.0
    with pytest.raises(InstrumentFault, match=r"not stable within ±0.001 K of 35 degC .* after 200 s"):
        ch.wait_stable(0.001, 200.0, clock, hold_s=60.0, poll_s=10.0)
    ch.close()
    cyc.close()


def test_cell_ambient_follows_the_chamber(make_lab) -> None:  # noqa: ANN001
    lab = make_lab(speed=20000.0, chamber=ChamberConfig(tau_s=60.0))
    ch = WatlowF4T.open(lab.chamber_url)
    ch.set_point(45.0)
    assert wait_until(lambda: lab.snapshot()["t_s"] > 4000.0, 5.0)
    T_cell = ScpiCycler.open(lab.cycler_url).measure().temperature_K
    assert T_cell is not None and T_cell - 273.15 > 40.0
    ch.close()


def test_f4t_with_rtu_framing_over_a_socket(make_lab) -> None:  # noqa: ANN001
    lab = make_lab()
    assert lab.rtu_url.startswith("modbus-rtu+socket://127.0.0.1:")
    ch = WatlowF4T.open(lab.rtu_url)
    assert ch.identify().startswith("Watlow F4T")
    ch.set_point(40.0)
    assert lab.chamber.sp_K == pytest.approx(313.15)
    assert 20.0 < ch.read() < 45.0
    ch.close()


def test_espec_over_tcp(make_lab) -> None:  # noqa: ANN001
    lab = make_lab()
    ch = EspecP300.open(lab.espec_url)
    assert ch.identify() == "Espec T,P300,150"
    ch.set_point(30.0)
    assert lab.chamber.sp_K == pytest.approx(303.15) and lab.chamber.running
    assert 24.0 < ch.read() < 31.0
    with pytest.raises(InputError, match="outside the chamber's limits"):
        ch.set_point(400.0)
    raw = LineAdapter(
        lab.espec_url.replace("espec://", "socket://"),
        write_terminator="\r\n",
        read_terminator="\r\n",
        timeout_s=1.0,
    )
    assert raw.query("TEMP, S999.0") == "NA:DATA OUT OF RANGE"
    assert raw.query("FROB?") == "NA:CMD ERR"
    raw.close()
    ch.close()


def test_chamber_alarm_reaches_every_client_and_interlocks_the_cycler(make_lab) -> None:  # noqa: ANN001
    lab = make_lab()
    cyc = ScpiCycler.open(lab.cycler_url)
    f4t, espec = WatlowF4T.open(lab.chamber_url), EspecP300.open(lab.espec_url)
    cyc.set_current(1.0)
    cyc.output(True)
    lab.trigger_chamber_alarm(code=7)
    t_alarm = lab.chamber.t
    with pytest.raises(InstrumentFault, match=r"chamber alarm: alarm 1 \(state 37\)"):
        f4t.read()
    with pytest.raises(InstrumentFault, match="chamber alarm: alarm code 7"):
        espec.read()
    state = cyc.protection()
    assert state.tripped and "INH" in state.causes
    assert lab.cycler.trips[-1].t_s - t_alarm <= 1.0
    lab.clear_chamber_alarm()
    assert f4t.alarms() == [] and espec.alarms() == []
    for d in (cyc, f4t, espec):
        d.close()


def test_cell_over_temperature_trips_the_output(make_lab) -> None:  # noqa: ANN001
    lab = make_lab()
    cyc = ScpiCycler.open(lab.cycler_url)
    cyc.set_temperature_limit(273.15 + 55.0)
    cyc.set_current(1.0)
    cyc.output(True)
    lab.force_cell_temperature(273.15 + 80.0)
    state = cyc.protection()
    assert state.tripped and "OT" in state.causes
    m = cyc.measure()
    assert (
        m.current_A == pytest.approx(0.0, abs=2e-3) and m.temperature_K is not None and m.temperature_K > 273.15 + 79.0
    )
    cyc.close()


def test_scheduled_device_faults(make_lab) -> None:  # noqa: ANN001
    lab = make_lab(device_faults=DeviceFaultPlan(chamber_alarm_at_s=300.0, chamber_alarm_code=2))
    cyc = ScpiCycler.open(lab.cycler_url)
    cyc.set_current(0.5)
    cyc.output(True)
    assert wait_until(lambda: lab.snapshot()["t_s"] > 400.0, 3.0)
    trip = lab.cycler.trips[-1]
    assert 300.0 <= trip.t_s <= 301.0 and "chamber alarm" in trip.reason
    assert lab.chamber.alarm_codes == [2]
    cyc.close()


def test_the_virtual_instrument_serves_the_dialect_it_is_given(make_lab) -> None:  # noqa: ANN001
    lab = make_lab(dialect=KEYSIGHT_N7900)
    cyc = ScpiCycler.open(lab.cycler_url, KEYSIGHT_N7900)
    assert cyc.identify().startswith("Keysight Technologies,N7951A")
    cyc.initialize()
    m = cyc.measure()
    assert isinstance(m, Measurement) and m.temperature_K is None and m.t_s is None
    assert isinstance(cyc.clock(), RealClock)
    cyc.adapter.write("MEAS:TEMP?")  # not in this dialect
    assert cyc.errors() == [(-113, "Undefined header")]
    cyc.close()


def test_hidden_effect_is_seen_over_the_wire(make_lab) -> None:  # noqa: ANN001
    plain = make_lab(noise=NOISELESS)
    wrapped = make_lab(noise=NOISELESS, effects=(lambda p: ContactResistance(p, 0.1),))
    volts = []
    for lab in (plain, wrapped):
        cyc = ScpiCycler.open(lab.cycler_url)
        cyc.set_current(2.0)
        cyc.output(True)
        volts.append(cyc.measure().voltage_V)
        cyc.output(False)
        cyc.close()
    assert volts[1] - volts[0] == pytest.approx(0.2, abs=0.005)


class ToyCell:
    """A minimal CellPhysics: a 3.3 V source with 10 mΩ, always at 30 °C."""

    limits = CellLimits()

    def __init__(self) -> None:
        self.voltage = 3.3

    def reset(self, soc0: float, T_amb_K: float) -> None:
        self.voltage = 3.3

    def step(self, current_A: float, dt_s: float, ambient_K: float) -> tuple[float, float]:
        self.voltage = 3.3 + 0.01 * current_A
        return self.voltage, 303.15


def test_any_cell_physics_can_be_injected(make_lab) -> None:  # noqa: ANN001
    lab = make_lab(ToyCell(), noise=NOISELESS)
    cyc = ScpiCycler.open(lab.cycler_url)
    cyc.set_current(5.0)
    cyc.output(True)
    m = cyc.measure()
    assert m.voltage_V == pytest.approx(3.35) and m.temperature_K == pytest.approx(303.15)
    cyc.close()


def test_open_instruments_virtual() -> None:
    cycler, chamber, lab = open_instruments("virtual", "virtual")
    try:
        assert lab is not None and cycler.identify().startswith("battlab")
        chamber.set_point(30.0)
        assert 20.0 < chamber.read() < 31.0
    finally:
        cycler.close()
        chamber.close()
        lab.stop()  # type: ignore[union-attr]


class SlowToBuildCell(ToyCell):
    """A cell whose first state takes real time to set up, as a compiled model does."""

    def reset(self, soc0: float, T_amb_K: float) -> None:
        time.sleep(0.3)
        super().reset(soc0, T_amb_K)


def test_time_starts_when_the_instruments_are_served(make_lab) -> None:  # noqa: ANN001
    # 0.3 s of set-up at 1000x would otherwise be 300 virtual seconds owed to the physics at the first tick,
    # computed while the first replies wait
    lab = make_lab(SlowToBuildCell(), speed=1000.0)
    assert lab.snapshot()["t_s"] < 100.0


def test_the_ticker_leaves_the_cell_alone_while_a_host_talks() -> None:
    """The ticker advances the instruments only after ``tick_real_s`` without any advance: a tick between a host's
    queries would split the physics into extra partial steps (and hold the lock while the next query waits)."""
    ports = {"cycler_port": None, "modbus_port": None, "modbus_rtu_port": None, "espec_port": None}
    lab = VirtualLab(None, VirtualLabConfig(speed=1000.0, tick_real_s=0.5, **ports))  # not started: no ticker
    lab.advance()
    steps, t = lab.cycler.physics_steps, lab.cycler.t
    assert not lab.tick()
    assert lab.cycler.physics_steps == steps and lab.cycler.t == t
    time.sleep(0.5)
    assert lab.tick()
    assert lab.cycler.physics_steps > steps and lab.cycler.t > t


def test_a_lock_step_lab_moves_only_as_its_host_sleeps(make_lab) -> None:  # noqa: ANN001
    """Lock-step clock: no ticker; time moves only as the host sleeps (the cell computed once per ``max_step_s``) and
    by ``exchange_s`` per message, never with real time; device faults fire when the clock crosses their times."""
    lab = make_lab(clock="lockstep", noise=NOISELESS, device_faults=DeviceFaultPlan(chamber_alarm_at_s=25.0))
    assert lab.clock.lockstep and lab._ticker is None and lab.config.exchange_s == 0.01
    cyc = ScpiCycler.open(lab.cycler_url)
    cyc.set_current_limits(5.4, 13.5)
    rest = cyc.measure()
    time.sleep(0.05)  # 50 virtual s on a free clock
    assert cyc.measure().t_s == pytest.approx(rest.t_s + 0.01)
    cyc.set_current(2.7)
    cyc.output(True)
    on = cyc.measure()
    assert on.current_A == pytest.approx(2.7) and on.voltage_V > rest.voltage_V + 2.7 * 0.03  # R0 of the stand-in
    steps = lab.cycler.physics_steps
    lab.clock.sleep(10.0)
    assert lab.cycler.physics_steps == steps + 10
    later = cyc.measure()
    assert later.t_s == pytest.approx(on.t_s + 10.01) and later.voltage_V > on.voltage_V
    lab.clock.sleep(20.0)  # crosses the chamber alarm at 25 s: the interlock turns the output off there
    assert not lab.cycler.output_on and lab.cycler.trips[-1].t_s == pytest.approx(25.0)
    with pytest.raises(ValueError, match="clock 'stopped'"):
        VirtualLab(None, VirtualLabConfig(clock="stopped"))
    cyc.close()


class _SlowCell(EquivalentCircuitCell):
    """A stand-in cell that takes 50 ms of real time per virtual second: at 1000x it cannot keep up with the clock."""

    def step(self, current_A: float, dt_s: float, ambient_K: float) -> tuple[float, float]:
        time.sleep(0.05 * dt_s)
        return super().step(current_A, dt_s, ambient_K)


def test_a_lab_whose_physics_falls_behind_its_clock_still_stops() -> None:
    cfg = VirtualLabConfig(speed=1000.0, cycler_port=None, modbus_port=None, modbus_rtu_port=None, espec_port=None)
    lab = VirtualLab(_SlowCell(), cfg).start()
    # each catch-up owes 50x the real time of the last one: after 10 ms, 0.5 s, then 25 s; stop during the third
    time.sleep(2.0)
    t0 = time.monotonic()
    lab.stop()
    assert lab._ticker is not None
    assert not lab._ticker.is_alive(), "the ticker was still catching up after stop()"
    assert time.monotonic() - t0 < 2.5
    assert lab.lock.acquire(timeout=1.0), "the lab's lock was still held after stop()"
    lab.lock.release()


def test_a_reading_just_after_a_current_step_carries_no_jitter_of_the_jump(make_lab) -> None:  # noqa: ANN001
    """A lock-step reading 10 ms (one message) after a 5 A step: the sample-time jitter error is jitter × the
    voltage's slope at the reading, not × (the whole jump / 10 ms), so the reading is the true voltage within the
    white and current noise (the jump is R0 × 5 A = 150 mV; 2 ms of jitter on it would add ~30 mV)."""
    from drivers.virtual.noise import NoiseModel

    noise = NoiseModel(voltage_white_V=0.0, voltage_per_amp_V=0.0, voltage_quantum_V=0.0)
    lab = make_lab(clock="lockstep", noise=noise, seed=1)
    cyc = ScpiCycler.open(lab.cycler_url)
    cyc.set_current_limits(5.4, 13.5)
    errors = []
    for k in range(10):
        cyc.set_current(-5.0 if k % 2 else 5.0)
        cyc.output(True)
        m = cyc.measure()
        errors.append(m.voltage_V - lab.cycler.v_true)
        cyc.output(False)
        lab.clock.sleep(60.0)
    cyc.close()
    assert max(map(abs, errors)) < 1e-3, f"readings off the true voltage by up to {1e3 * max(map(abs, errors)):.1f} mV"
