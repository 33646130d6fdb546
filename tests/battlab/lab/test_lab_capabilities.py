"""The runner asks an instrument's declared capabilities (drivers.interfaces) instead of probing it: which clock times
the run, which protections are programmed, whose time stamps are used; an operation an instrument lacks is
NotSupported, not a user's mistake, and the CLI says so in one line. The instruments here are in-memory drivers
registered under their own URL schemes, as a new driver would be."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner
from lab_helpers import plan_from

from battlab.cli import main
from battlab.lab.bench import RunSettings, open_bench
from battlab.lab.calls import InstrumentCalls
from battlab.lab.documents import Subscriber
from battlab.lab.engine import EngineConfig, RunEngine, RunState
from battlab.lab.limits import VIRTUAL_LIMITS, Envelope
from battlab.lab.plan import RunOptions
from battlab.lab.prepare import prepare_bench
from battlab.lab.run_state import Abort, RunStats
from drivers import registry
from drivers.clock import RealClock
from drivers.defaults import ChamberDefaults, CyclerDefaults
from drivers.errors import NotSupported
from drivers.interfaces import CyclerCapabilities, Measurement, ProtectionState
from drivers.registry import CHAMBER, CYCLER, OpenOptions, UrlScheme
from drivers.testing import contract_problems
from drivers.urls import InstrumentURL
from protocols.errors import InputError

ENV = Envelope(2.5, 4.2, 5.0, 5.0, 318.15)
EVERYTHING = CyclerCapabilities(
    clock=True,
    timestamps=True,
    low_voltage_cutoff=True,
    temperature_limit=True,
    watchdog=True,
    clear_protection=True,
    link_timeout=True,
)


class JumpClock:
    """A run clock that jumps to where it is slept to; ``speed``: its seconds per real second."""

    def __init__(self, speed: float = float("inf")) -> None:
        self.speed = speed
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def sleep(self, dt_s: float) -> None:
        self.t += max(0.0, dt_s)


class MemCycler(CyclerDefaults):
    """A resistor on a current source, in memory; records what the runner asks of it. Its optional operations work
    whatever it declares (on purpose: no driver should), so only the runner's reading of ``capabilities`` decides
    whether they are called. ``stamp_offset_s``: its samples' time stamps run this far ahead of ``clock`` (a time
    base of its own)."""

    def __init__(
        self, capabilities: CyclerCapabilities, clock: JumpClock | None = None, stamp_offset_s: float = 0.0
    ) -> None:
        self.name = "mem cycler"
        self.capabilities = capabilities
        self._clock = clock or JumpClock()
        self.stamp_offset_s = stamp_offset_s
        self.asked: list[tuple[str, tuple[Any, ...]]] = []
        self.i = 0.0
        self.on = False
        self._timeout = 1.0

    def _note(self, what: str, *args: Any) -> None:
        self.asked.append((what, args))

    def names(self) -> list[str]:
        return [what for what, _ in self.asked]

    @property
    def link_timeout_s(self) -> float | None:
        return self._timeout

    @link_timeout_s.setter
    def link_timeout_s(self, timeout_s: float) -> None:
        self._note("link_timeout_s", timeout_s)
        self._timeout = timeout_s

    def clock(self) -> JumpClock:
        self._note("clock")
        if not self.capabilities.clock:
            raise AssertionError("a cycler without a clock was asked for one")
        return self._clock

    def identify(self) -> str:
        return "mem,cycler,0,1"

    def initialize(self) -> None:
        self.i, self.on = 0.0, False

    def set_current(self, current_A: float) -> None:
        self.i = current_A

    def output(self, on: bool) -> None:
        self.on = on

    def measure(self) -> Measurement:
        i = self.i if self.on else 0.0
        return Measurement(3.7 + 0.05 * i, i, 298.15, self._clock.t + self.stamp_offset_s)

    def set_voltage_limits(self, low_V: float | None, high_V: float) -> None:
        self._note("set_voltage_limits", low_V, high_V)

    def set_current_limits(self, charge_A: float, discharge_A: float) -> None: ...

    def set_temperature_limit(self, T_max_K: float) -> None:
        self._note("set_temperature_limit", T_max_K)

    def protection(self) -> ProtectionState:
        return ProtectionState(False)

    def clear_protection(self) -> None:
        self._note("clear_protection")

    def errors(self) -> list[tuple[int, str]]:
        return []

    def set_watchdog(self, timeout_s: float | None) -> None:
        self._note("set_watchdog", timeout_s)

    def safe_off(self) -> bool:
        self.on = False
        return True

    def close(self) -> None:
        self._note("close")


class MemChamber(ChamberDefaults):
    name = "mem chamber"

    def identify(self) -> str:
        return "mem chamber"

    def set_point(self, T_degC: float) -> None: ...

    def read(self) -> float:
        return 25.0

    def alarms(self) -> list[str]:
        return []

    def wait_stable(
        self, tol: float, timeout: float, clock: Any, *, hold_s: float = 60.0, poll_s: float = 5.0
    ) -> float:
        return 25.0

    def close(self) -> None: ...


# -- the bench: opened by URL, timed by the cycler's clock only where it has one -------------------------------------
OPENED: list[MemCycler] = []


def _open_mem_cycler(url: InstrumentURL, options: OpenOptions) -> MemCycler:
    channel = url.option("channel")
    if channel not in (None, "1"):
        raise NotSupported(f"cycler[{url.raw}]", f"channel {channel}", "the instrument has one channel")
    speed = url.float_option("speed", 0.0)
    cyc = MemCycler(EVERYTHING if speed else CyclerCapabilities(), JumpClock(speed) if speed else None)
    OPENED.append(cyc)
    return cyc


@pytest.fixture
def mem_drivers() -> Iterator[None]:
    """``mem-cycler://HOST:PORT[?speed=S][&channel=N]`` and ``mem-chamber://HOST:PORT``, registered for the test."""
    options = frozenset({"timeout", "speed", "channel"})
    cycler = registry.register(CYCLER, MemCycler, UrlScheme("mem-cycler", options), opener=_open_mem_cycler)
    chamber = registry.register(CHAMBER, MemChamber, UrlScheme("mem-chamber"), opener=lambda u, o: MemChamber())
    OPENED.clear()
    yield
    registry.unregister(cycler)
    registry.unregister(chamber)


def test_a_cycler_without_a_clock_runs_on_the_real_clock(mem_drivers: None) -> None:
    settings = RunSettings("mem-cycler://127.0.0.1:1", "mem-chamber://127.0.0.1:2")
    bench = open_bench(settings, None, VIRTUAL_LIMITS, 25.0)
    bench.close()
    (cyc,) = OPENED
    assert isinstance(bench.clock, RealClock) and bench.speed == 1.0
    assert cyc.names() == ["close"]  # neither asked for a clock nor given a link timeout it cannot take


def test_a_cycler_with_a_clock_times_the_run_and_its_link_timeout_follows_it(mem_drivers: None) -> None:
    settings = RunSettings("mem-cycler://127.0.0.1:1?speed=100", "mem-chamber://127.0.0.1:2")
    bench = open_bench(settings, None, VIRTUAL_LIMITS, 25.0)
    bench.close()
    (cyc,) = OPENED
    assert bench.clock is cyc._clock and bench.speed == 100.0
    assert cyc.asked == [("clock", ()), ("link_timeout_s", (0.15,)), ("close", ())]  # 15 virtual s at 100x


def test_a_url_timeout_option_keeps_the_link_timeout(mem_drivers: None) -> None:
    settings = RunSettings("mem-cycler://127.0.0.1:1?speed=100&timeout=3", "mem-chamber://127.0.0.1:2")
    open_bench(settings, None, VIRTUAL_LIMITS, 25.0).close()
    assert OPENED[0].names() == ["clock", "close"]


# -- the preflight: each protection programmed where the cycler declares it ----------------------------------------
def _prepare(cyc: MemCycler) -> list[str]:
    clock = JumpClock()
    stats = RunStats()
    calls = InstrumentCalls(0, 0.0, clock, stats)
    options = RunOptions(stable_hold_s=0.0)
    ready = prepare_bench(calls, cyc, MemChamber(), ENV, options, EngineConfig(envelope=ENV, clock=clock), clock)
    return ready.notes + stats.notes


def test_a_cycler_with_no_protections_is_never_asked_for_them() -> None:
    cyc = MemCycler(CyclerCapabilities())
    notes = " | ".join(_prepare(cyc))
    assert "set_temperature_limit" not in cyc.names() and "set_watchdog" not in cyc.names()
    assert "clear_protection" not in cyc.names()
    assert ("set_voltage_limits", (None, 4.2)) in cyc.asked
    assert "runner enforces voltage_min" in notes
    assert "over-temperature trip: not available" in notes and "watchdog: not available" in notes


def test_a_cycler_with_every_protection_gets_them_all_from_the_envelope() -> None:
    cyc = MemCycler(EVERYTHING)
    notes = " | ".join(_prepare(cyc))
    assert ("set_voltage_limits", (2.5, 4.2)) in cyc.asked
    assert ("set_temperature_limit", (318.15,)) in cyc.asked and ("set_watchdog", (60.0,)) in cyc.asked
    assert "clear_protection" in cyc.names()
    assert "not available" not in notes and "voltage_min" not in notes


def test_a_declared_protection_the_instrument_refuses_is_noted() -> None:
    class Refusing(MemCycler):
        def set_watchdog(self, timeout_s: float | None) -> None:
            raise InputError(f"{self.name}: watchdog delay {timeout_s} s is outside the instrument's range [1, 30]")

    notes = " | ".join(_prepare(Refusing(EVERYTHING)))
    assert "watchdog: not available (mem cycler: watchdog delay 60.0 s is outside" in notes


class NoWatchdog(MemCycler):
    set_watchdog = CyclerDefaults.set_watchdog  # NotSupported


def test_an_undeclared_operation_called_anyway_aborts_as_unsupported() -> None:
    calls = InstrumentCalls(0, 0.0, JumpClock(), RunStats())
    cyc = NoWatchdog(CyclerCapabilities())
    with pytest.raises(Abort) as info:
        calls.call("watchdog", cyc.set_watchdog, 60.0)
    assert info.value.kind == "unsupported" and "an instrument watchdog is not supported" in info.value.message
    assert not calls.optional("watchdog", cyc.set_watchdog, 60.0)
    assert calls.stats.notes == [
        "watchdog: not available (mem cycler: an instrument watchdog is not supported); runner-side checks only"
    ]


# -- the run: whose time stamps are used ----------------------------------------------------------------------------
RUN = """
name = "stamps"
[run]
stable_hold_s = 0
[[steps]]
kind = "rest"
until = "time >= 3"
[[steps]]
kind = "cc"
current = -1.0
until = "time >= 3"
"""


class Rows(Subscriber):
    def __init__(self) -> None:
        self.rows: list[tuple[float, ...]] = []

    def event(self, row: tuple[float, ...]) -> None:
        self.rows.append(row)


@pytest.mark.parametrize("declared", [False, True])
def test_samples_are_timed_by_the_instrument_only_where_it_declares_time_stamps(declared: bool, tmp_path: Path) -> None:
    """Both cyclers stamp their samples 1000 s ahead of the run clock; only one declares that its stamps are on the
    clock it gives the runner. The other's samples are timed by the run clock, so the run takes 6 s of it."""
    clock = JumpClock()
    caps = CyclerCapabilities(clock=declared, timestamps=declared)
    cyc = MemCycler(caps, clock, stamp_offset_s=1000.0 if not declared else 0.0)
    rows = Rows()
    engine = RunEngine(plan_from(RUN, tmp_path), cyc, MemChamber(), EngineConfig(envelope=ENV, clock=clock), [rows])
    assert engine.run() is RunState.COMPLETED
    assert [round(r[0], 9) for r in rows.rows] == [0.0, 1.0, 2.0, 3.0, 3.0, 4.0, 5.0, 6.0]
    assert clock.t < 10.0


def test_the_cli_reports_an_unsupported_request_in_one_line(mem_drivers: None, home: Path, tmp_path: Path) -> None:
    plan = tmp_path / "plan.toml"
    plan.write_text(RUN)
    out = tmp_path / "run.h5"
    url = "mem-cycler://127.0.0.1:1?channel=3"
    args = ["run", str(plan), "--cycler", url, "--chamber", "mem-chamber://127.0.0.1:2", "-o", str(out)]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 2
    assert result.output.strip() == f"error: cycler[{url}]: channel 3 is not supported (the instrument has one channel)"
    assert not out.exists()


def test_the_campaigns_in_process_instruments_keep_the_contract() -> None:
    """The lock-step tester's cycler and chamber, which the same engine runs on. Built without a lab: each
    operation they declare then fails on the missing lab, which the check allows; what they leave out must still
    be NotSupported without touching it."""
    from battlab.campaign.tester import LockstepChamber, LockstepCycler

    assert contract_problems(LockstepCycler.__new__(LockstepCycler), "cycler") == []
    assert contract_problems(LockstepChamber.__new__(LockstepChamber), "chamber") == []
