"""Protocol tests from recorded command/response pairs (tests/drivers/recordings/*.txt).

Each recording has a scenario that drives the real driver against a replaying adapter; the adapter fails
on an unexpected command, and the test fails if any recorded pair is left unused (pymeasure's idea).
Every recording file must have a scenario, so none can rot unnoticed.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from drivers.chambers.espec import EspecP300
from drivers.chambers.watlow_f4t import WatlowF4T
from drivers.errors import CommunicationError, InstrumentFault, NotSupported, ReplyError
from drivers.scpi.cycler import ScpiCycler
from drivers.scpi.dialects import BATTLAB_VIRTUAL, KEYSIGHT_N7900
from drivers.testing import ReplayAdapter, ReplayRegisters, load_recording, parse_recording
from protocols.errors import InputError

RECORDINGS = Path(__file__).parent / "recordings"


def n7900_session(adapter: ReplayAdapter) -> None:
    cyc = ScpiCycler(adapter, KEYSIGHT_N7900, name="n7900")
    assert cyc.identify().startswith("Keysight Technologies,N7951A")
    cyc.initialize()
    cyc.set_voltage_limits(None, 4.2)
    cyc.set_current_limits(charge_A=2.7, discharge_A=2.0)
    cyc.set_watchdog(9.2)  # whole seconds on the N7900: rounded up to 10
    cyc.set_current(1.35)
    cyc.output(True)
    m = cyc.measure()
    assert (m.voltage_V, m.current_A, m.temperature_K, m.t_s) == (3.7123, 1.35012, None, None)
    assert not cyc.protection().tripped
    cyc.set_current(-1.0)
    assert cyc.measure().current_A == pytest.approx(-0.99987)
    cyc.output(False)
    state = cyc.protection()
    assert state.tripped and state.causes == {"PROT"} and state.raw == 2048
    cyc.clear_protection()


def n7900_errors(adapter: ReplayAdapter) -> None:
    cyc = ScpiCycler(adapter, KEYSIGHT_N7900, name="n7900", retries=2)
    with pytest.raises(InstrumentFault, match=r"rejected: -222,'Data out of range'; also \[\(-221"):
        cyc.set("current", 1.5)
    cyc.output(True)
    assert adapter.recoveries == 1
    assert cyc.measure().voltage_V == 3.7
    assert adapter.recoveries == 2
    with pytest.raises(CommunicationError, match="measure failed after 3 attempts") as info:
        cyc.measure()
    assert isinstance(info.value, ReplyError) and "garbage" in str(info.value)


def virtual_session(adapter: ReplayAdapter) -> None:
    cyc = ScpiCycler(adapter, BATTLAB_VIRTUAL, name="virtual")
    assert cyc.identify().startswith("battlab,")
    cyc.set_voltage_limits(2.5, 4.2)
    cyc.set_temperature_limit(333.15)
    cyc.set_current(2.7)
    assert cyc.last_applied_t_s == 120.0  # the instrument's time of the step, from the same round trip
    m = cyc.measure()
    assert m.voltage_V == 3.6012 and m.current_A == 2.70008
    assert m.temperature_K == pytest.approx(298.30) and m.t_s == pytest.approx(123.456789)
    state = cyc.protection()
    assert state.tripped and state.causes == {"OT", "PROT", "WDOG"}


def espec_session(adapter: ReplayAdapter) -> None:
    ch = EspecP300(adapter, name="p300")
    assert ch.identify() == "Espec T,P300,150"
    ch.set_point(35.0)
    assert ch.read() == 24.1
    with pytest.raises(InstrumentFault, match="chamber alarm: alarm code 25"):
        ch.read()
    with pytest.raises(InstrumentFault, match=r"refused: DATA OUT OF RANGE \(data not within the valid"):
        ch.set_point(-20.0)


def f4t_session(registers: ReplayRegisters) -> None:
    ch = WatlowF4T(registers, name="f4t")
    assert ch.identify() == "Watlow F4T F4T1L1AA1A2AAAA"
    ch.set_point(35.0)
    assert ch.read() == 25.0
    with pytest.raises(InstrumentFault, match=r"alarm 1 \(state 37\)"):
        ch.read()


def f4t_fahrenheit(registers: ReplayRegisters) -> None:
    ch = WatlowF4T(registers, name="f4t")
    assert ch.read() == pytest.approx(25.0)
    assert ch.range_C() == pytest.approx((-40.0, 148.8889), abs=1e-3)
    ch.set_point(35.0)


SCENARIOS: dict[str, tuple[Callable[..., None], type]] = {
    "n7900_session.txt": (n7900_session, ReplayAdapter),
    "n7900_errors.txt": (n7900_errors, ReplayAdapter),
    "virtual_session.txt": (virtual_session, ReplayAdapter),
    "espec_session.txt": (espec_session, ReplayAdapter),
    "f4t_session.txt": (f4t_session, ReplayRegisters),
    "f4t_fahrenheit.txt": (f4t_fahrenheit, ReplayRegisters),
}


def test_every_recording_has_a_scenario() -> None:
    files = {p.name for p in RECORDINGS.glob("*.txt")}
    assert files == set(SCENARIOS), f"recordings without scenario: {files - set(SCENARIOS)}"


@pytest.mark.parametrize("filename", sorted(SCENARIOS))
def test_recorded_session(filename: str) -> None:
    scenario, adapter_type = SCENARIOS[filename]
    replay = adapter_type(load_recording(RECORDINGS / filename), name=filename)
    scenario(replay)
    replay.assert_all_used()


def test_replay_fails_on_unused_pairs() -> None:
    replay = ReplayAdapter(parse_recording('> *IDN?\n< a,b,c,d\n> OUTP 0;:SYST:ERR?\n< +0,"No error"\n'))
    ScpiCycler(replay, KEYSIGHT_N7900).identify()
    with pytest.raises(AssertionError, match="1 recorded pair"):
        replay.assert_all_used()


def test_replay_fails_on_unexpected_command() -> None:
    replay = ReplayAdapter(parse_recording('> OUTP 1;:SYST:ERR?\n< +0,"No error"\n'))
    with pytest.raises(AssertionError, match="recording expects 'OUTP 1;:SYST:ERR\\?'"):
        ScpiCycler(replay, KEYSIGHT_N7900).output(False)


def test_recording_syntax_errors_name_the_line() -> None:
    with pytest.raises(ValueError, match="x.txt:2: reply without a command"):
        parse_recording("# c\n< orphan\n", "x.txt")
    with pytest.raises(ValueError, match="x.txt:1: expected"):
        parse_recording("hello\n", "x.txt")


def test_out_of_range_setting_is_a_user_error_before_any_io() -> None:
    replay = ReplayAdapter([])
    cyc = ScpiCycler(replay, KEYSIGHT_N7900)
    with pytest.raises(InputError, match="current 30 A is outside the configured limits"):
        cyc.set_current(30.0)
    with pytest.raises(InputError, match=r"watchdog_delay .*outside the instrument's range \[1, 3600\]"):
        cyc.set_watchdog(7200)
    with pytest.raises(NotSupported, match="no low-voltage cutoff"):
        cyc.set_voltage_limits(2.5, 4.2)
    replay.assert_all_used()
