"""Unit tests of the runner's parts: plans, limits files, pre-flight, step executors, CV regulation, safety checks,
the run catalog and the resume copy of a log."""

from __future__ import annotations

import contextlib
import math
import socket
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from lab_helpers import plan_from

from battlab.cell import Cell
from battlab.io.logs import open_log, read_log
from battlab.lab import logfile
from battlab.lab.calls import MIN_RETRY_TIMEOUT_S, InstrumentCalls
from battlab.lab.catalog import Catalog, RunLock
from battlab.lab.documents import LogSink, RunStart
from battlab.lab.engine import HEARTBEAT_S, RunEngine
from battlab.lab.limits import VIRTUAL_LIMITS, CellWindow, Envelope, InstrumentLimits
from battlab.lab.plan import Plan
from battlab.lab.preflight import check_plan
from battlab.lab.run_state import Abort, RunStats
from battlab.lab.safety import check_sample, safe_shutdown
from battlab.lab.steps import (
    CCCVExecutor,
    CCExecutor,
    CVExecutor,
    ProfileExecutor,
    ResistanceEstimate,
    Sample,
)
from drivers.chambers.watlow_f4t import WatlowF4T
from drivers.clock import RealClock
from drivers.interfaces import Measurement
from drivers.scpi.cycler import ScpiCycler
from protocols import Profile
from protocols.errors import InputError
from protocols.protocol import CCCV, ConstantCurrent, ConstantVoltage, ProfileStep

PROFILE = "[[steps]]\nkind = 'profile'\nprofile = {{ t = [0, 1, 2], current = [{i}, {i}, 0], soc0 = 0.5 }}\n"
REST = "[[steps]]\nkind = 'rest'\nuntil = 'time >= 10'\n"


@pytest.fixture(scope="module")
def window() -> CellWindow:
    return CellWindow.of(Cell.load("nca18650"))


# -- plans --------------------------------------------------------------------------------------------------
def test_repeat_runs_each_profile_block_and_trailing_steps_once(tmp_path: Path) -> None:
    text = "[run]\nrepeat = 2\n" + REST + PROFILE.format(i=1.0) + REST + PROFILE.format(i=-1.0) + REST
    plan = plan_from(text, tmp_path)
    got = [(e.step_index, e.trial) for e in plan.entries()]
    assert got == [(1, 1), (2, 1), (1, 2), (2, 2), (3, 1), (4, 1), (3, 2), (4, 2), (5, 1)]
    assert [e.entry for e in plan.entries()] == list(range(9))
    assert plan.entries()[2].label.endswith("(trial 2)")


def test_plan_round_trips_through_the_catalog_form(tmp_path: Path) -> None:
    plan = plan_from("[run]\nsample_period_s = 0.5\nambient_degC = 30\n" + REST + PROFILE.format(i=2.0), tmp_path)
    back = Plan.from_dict(plan.to_dict(), source="catalog")
    assert back.options == plan.options
    assert [type(e.step) for e in back.entries()] == [type(e.step) for e in plan.entries()]
    np.testing.assert_array_equal(back.protocol.steps[1].profile.current, plan.protocol.steps[1].profile.current)


@pytest.mark.parametrize(
    ("run_table", "expected"),
    [
        ("sample_perid_s = 1", "unknown field(s) ['sample_perid_s']"),
        ("repeat = 0", "repeat must be a whole number >= 1"),
        ("sample_period_s = -1", "sample_period_s must be positive"),
        ("cv_gain = 2", "cv_gain must be in (0, 1]"),
    ],
)
def test_run_table_errors_name_the_file_and_field(tmp_path: Path, run_table: str, expected: str) -> None:
    with pytest.raises(InputError) as err:
        plan_from(f"[run]\n{run_table}\n" + REST, tmp_path)
    assert "plan.toml" in str(err.value) and expected in str(err.value)


# -- limits files and pre-flight ----------------------------------------------------------------------------
LIMITS = """
[cycler]
dialect = "keysight-n7951a"
voltage_min = 0.0
voltage_max = 20.0
current_charge_max = 20.0
current_discharge_max = 2.0
[chamber]
temperature_min = -40.0
temperature_max = 150.0
safe_set_point = 22.0
"""


def test_limits_file_is_read(tmp_path: Path) -> None:
    path = tmp_path / "bench.toml"
    path.write_text(LIMITS)
    lim = InstrumentLimits.load(path)
    assert lim.cycler.current_discharge_max == 2.0 and lim.cycler.dialect == "keysight-n7951a"
    assert lim.chamber.safe_set_point == 22.0 and lim.source == str(path)


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (("current_discharge_max = 2.0\n", ""), "missing field 'current_discharge_max'"),
        (("voltage_max = 20.0", "voltage_maxx = 20.0"), "unknown field(s) ['voltage_maxx']"),
        (("safe_set_point = 22.0", "safe_set_point = 200.0"), "safe_set_point 200"),
        (("voltage_min = 0.0", "voltage_min = 'low'"), "voltage_min must be a number"),
    ],
)
def test_limits_file_errors_name_the_table_and_field(tmp_path: Path, edit: tuple[str, str], expected: str) -> None:
    path = tmp_path / "bench.toml"
    path.write_text(LIMITS.replace(*edit))
    with pytest.raises(InputError) as err:
        InstrumentLimits.load(path)
    assert str(path) in str(err.value) and expected in str(err.value)


def test_preflight_envelope_is_the_tightest_of_plan_cell_and_instrument(tmp_path: Path, window: CellWindow) -> None:
    path = tmp_path / "bench.toml"
    path.write_text(LIMITS)
    plan = plan_from("[limits]\ncurrent_max = 10.0\ntemperature_max = 318.15\n" + PROFILE.format(i=1.5), tmp_path)
    env = check_plan(plan, window, InstrumentLimits.load(path))
    assert env == Envelope(2.45, 4.25, 10.0, 2.0, 318.15)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        (PROFILE.format(i=-3.0), "step 1 (profile): current -3 A exceeds the discharge limit 2 A"),
        ("[limits]\nvoltage_max = 4.4\n" + REST, "exceeds cell nca18650's window"),
        ("[run]\nambient_degC = 49\n" + REST, "within 2 K of the surface-temperature limit"),
        (REST + "[[steps]]\nkind = 'cv'\nvoltage = 2.47\nuntil = 'time >= 5'\n", "outside cell nca18650's window"),
    ],
)
def test_preflight_rejects_a_plan_beyond_a_limit(tmp_path: Path, window: CellWindow, text: str, expected: str) -> None:
    path = tmp_path / "bench.toml"
    path.write_text(LIMITS)
    plan = plan_from(text, tmp_path)
    with pytest.raises(InputError) as err:
        check_plan(plan, window, InstrumentLimits.load(path))
    assert "plan.toml" in str(err.value) and expected in str(err.value)


def test_virtual_limits_accept_the_library_bound(tmp_path: Path, window: CellWindow) -> None:
    env = check_plan(plan_from(PROFILE.format(i=-13.5), tmp_path), window, VIRTUAL_LIMITS)
    assert env.current_discharge_max == pytest.approx(13.5)


# -- step executors -----------------------------------------------------------------------------------------
def test_profile_executor_samples_at_breakpoints_and_holds_the_current() -> None:
    prof = Profile(np.array([0.0, 0.5, 2.0, 3.0]), np.array([1.0, 2.0, 3.0, 3.0]))
    ex = ProfileExecutor(ProfileStep(prof), period_s=1.0)
    ex.begin(10.0, None)
    ticks, t = [10.0], 10.0
    while t < 13.0:
        t = ex.next_tick(t)
        ticks.append(t)
    assert ticks == [10.0, 10.5, 11.0, 12.0, 13.0]
    assert [ex.command(x) for x in (10.0, 10.49, 10.5, 11.9, 12.7, 13.0)] == [1.0, 1.0, 2.0, 2.0, 3.0, 3.0]
    assert ex.observe(Sample(12.9, 3.7, 3.0)) is None
    assert ex.observe(Sample(13.0, 3.7, 3.0)) == "end of profile"


def test_cc_ends_on_charge_moved_and_on_voltage() -> None:
    ex = CCExecutor(ConstantCurrent(-2.0, ("capacity >= 0.001", "voltage <= 3.0")), 1.0)
    ex.begin(0.0, None)
    assert ex.observe(Sample(1.0, 3.5, -2.0)) is None  # 2 A s
    assert ex.observe(Sample(2.0, 3.5, -2.0)) == "capacity >= 0.001"  # 4 A s >= 3.6 A s
    ex.begin(5.0, None)
    assert ex.observe(Sample(6.0, 2.99, -2.0)) == "voltage <= 3"
    assert ex.next_tick(6.2) == 7.0


def test_cccv_current_end_applies_only_once_the_voltage_is_held() -> None:
    res = ResistanceEstimate(0.05)
    ex = CCCVExecutor(CCCV(-1.0, 3.5, ("current <= 0.5", "time >= 100")), 1.0, 0.5, res)
    ex.begin(0.0, None)
    assert ex.command(0.0) == -1.0 and not ex.cv
    assert ex.observe(Sample(1.0, 3.6, -0.2)) is None  # |I| small but still CC: no end
    assert ex.observe(Sample(2.0, 3.49, -1.0)) is None and ex.cv  # crossed: CV from here
    assert -1.0 <= ex.command(2.0) <= 0.0
    assert ex.observe(Sample(3.0, 3.45, -0.3)) is None  # 50 mV off the target: not settled
    assert ex.observe(Sample(4.0, 3.501, -0.3)) == "current <= 0.5"


@settings(max_examples=60, deadline=None)
@given(
    r_true=st.floats(0.005, 0.25),
    r_guess=st.floats(0.01, 0.5),
    ocv0=st.floats(3.4, 3.9),
    sign=st.sampled_from([1, -1]),
)
def test_cv_regulation_holds_the_voltage_without_reversing_the_current(
    r_true: float, r_guess: float, ocv0: float, sign: int
) -> None:
    """A cell with an OCV that follows the charge, an ohmic part and an RC pair: the CV step holds its voltage
    to a few millivolts, never reverses the current, never exceeds its bound, and ends on its taper."""
    target = ocv0 + sign * 0.05
    res = ResistanceEstimate(r_guess)
    ex = CVExecutor(
        ConstantVoltage(target, ("current <= 0.1", "time >= 30000"), "charge" if sign > 0 else "discharge"),
        1.0,
        2.7,
        0.5,
        res,
    )
    ocv, v_rc, t, v = ocv0, 0.0, 0.0, ocv0
    ex.begin(t, Sample(t, v, 0.0))
    currents, volts, ended = [], [], None
    for _ in range(30000):
        i = ex.command(t)
        v_rc = v_rc * math.exp(-1 / 30) + i * 0.01 * (1 - math.exp(-1 / 30))
        v = ocv + r_true * i + v_rc
        s = Sample(t, v, i)
        res.observe(s)
        ended = ex.observe(s)
        currents.append(i)
        volts.append(v)
        ocv += i / 3600 / 2.7 * 0.5
        t += 1.0
        if ended:
            break
    currents, volts = np.array(currents), np.array(volts)
    assert ended == "current <= 0.1"
    assert np.all(sign * currents >= 0) and np.all(np.abs(currents) <= 2.7)
    assert abs(volts[-1] - target) <= 0.01
    assert np.max(np.abs(volts[100:] - target)) < 0.005


# -- safety ---------------------------------------------------------------------------------------------------
ENV = Envelope(2.5, 4.2, 5.0, 3.0, 318.15)


@pytest.mark.parametrize(
    ("sample", "kind"),
    [
        (Sample(1.0, 3.7, 1.0, 300.0), None),
        (Sample(1.0, 2.49, -1.0, 300.0), "voltage"),
        (Sample(1.0, float("nan"), -1.0, 300.0), "voltage"),
        (Sample(1.0, 3.7, -3.2, 300.0), "current"),
        (Sample(1.0, 3.7, 5.05, 300.0), None),  # within the measurement tolerance
        (Sample(1.0, 3.7, 1.0, 318.2), "temperature"),
        (Sample(1.0, 3.7, 1.0, None), None),
    ],
)
def test_check_sample(sample: Sample, kind: str | None) -> None:
    bad = check_sample(sample, ENV)
    assert (bad.kind if bad else None) == kind


def test_the_safe_shutdown_of_a_dead_link_sends_output_off_without_waiting_for_it(tmp_path: Path) -> None:
    """A hung tester (accepts, never answers): output off is written once, no reply is waited for (the link's
    timeout here is 5 s), nothing else is asked of it, and the shutdown says so."""
    received = bytearray()
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        cycler = ScpiCycler.open(f"socket://127.0.0.1:{server.getsockname()[1]}", timeout_s=5.0, retries=0)
        conn, _ = server.accept()
        with conn:
            conn.settimeout(0.5)
            w0 = time.perf_counter()
            out = safe_shutdown(cycler, None, None, clock=RealClock(), unreachable=(cycler,))
            elapsed = time.perf_counter() - w0
            with contextlib.suppress(TimeoutError):
                while chunk := conn.recv(4096):
                    received += chunk
        cycler.close()
    assert elapsed < 2.5  # a generous bound: waiting for the reply would take the 5 s timeout
    assert bytes(received).splitlines() == [b"OUTP 0"]
    assert not out.output_off_confirmed and out.output_off_sent_t_s is not None and out.t_s >= out.output_off_sent_t_s
    assert out.current_after_A is None and any("not confirmed" in p for p in out.problems)


class StepClock:
    """A 1x clock that moves only when slept on, standing in for the engine in :meth:`RunEngine._wait_until`:
    records the times it watched the instruments."""

    speed = 1.0

    def __init__(self) -> None:
        self.t = 0.0
        self.heartbeats: list[float] = []
        self.stats = RunStats()
        self._stop_reason = None
        self.clock = self

    def now(self) -> float:
        return self.t

    def sleep(self, dt_s: float) -> None:
        self.t += max(0.0, dt_s)

    def _heartbeat(self) -> None:
        self.heartbeats.append(self.t)


@pytest.mark.parametrize("wait_s", [0.05, 0.2, 0.21, 0.29, 0.5, 0.79, 0.99, 3.3])
def test_between_samples_the_instruments_are_watched_at_most_a_heartbeat_apart(wait_s: float) -> None:
    """At 1x a dead link is noticed at the next exchange: no stretch without one is longer than HEARTBEAT_S, and
    there are no more watches than that needs."""
    fake = StepClock()
    RunEngine._wait_until(fake, wait_s)  # type: ignore[arg-type]
    times = [0.0, *fake.heartbeats, fake.t]
    assert fake.t == pytest.approx(wait_s)
    assert max(np.diff(times)) <= HEARTBEAT_S + 1e-9
    assert len(fake.heartbeats) == math.ceil(wait_s / HEARTBEAT_S - 1e-9) - 1


class SilentServer:
    """A loopback TCP server that accepts every connection and never answers (a hung instrument); counts them."""

    def __init__(self) -> None:
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.sock.settimeout(0.05)
        self.port = int(self.sock.getsockname()[1])
        self.connections: list[socket.socket] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._accept, daemon=True)
        self._thread.start()

    def _accept(self) -> None:
        while not self._stop.is_set():
            with contextlib.suppress(TimeoutError, OSError):
                self.connections.append(self.sock.accept()[0])

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        for c in [*self.connections, self.sock]:
            c.close()


def test_after_a_dead_cycler_link_a_hung_chamber_is_asked_once(tmp_path: Path) -> None:
    """The tester hung (cycler and chamber in one process): the safe shutdown sends output off and asks the chamber
    for its safe set point once, without the chamber driver's retries (each a link timeout more)."""
    cycler_side, chamber_side = SilentServer(), SilentServer()
    try:
        cycler = ScpiCycler.open(f"socket://127.0.0.1:{cycler_side.port}", timeout_s=0.1, retries=0)
        chamber = WatlowF4T.open(f"modbus-tcp://127.0.0.1:{chamber_side.port}", timeout_s=0.1, retries=2)
        try:
            out = safe_shutdown(cycler, chamber, 25.0, clock=RealClock(), unreachable=(cycler,))
        finally:
            cycler.close()
            chamber.close()
        assert len(chamber_side.connections) == 1  # one attempt: a retry reconnects first
        assert chamber.retries == 2  # the driver's setting is restored
        assert out.chamber_set_point_degC is None and any("chamber to 25 degC" in p for p in out.problems)
    finally:
        cycler_side.close()
        chamber_side.close()


def test_a_retry_to_a_hung_instrument_gets_what_is_left_of_the_budget() -> None:
    """A hung instrument at 1x (link timeout 0.2 s, budget 0.35 s): the first attempt times out after its whole link
    timeout, so the retry's link timeout is cut to what is left of the budget (at most 0.15 s, at least the 0.05 s
    floor), not another 0.2 s; then the call aborts and the driver's timeout is restored. The timeouts each attempt
    was given are recorded, no wall time is asserted."""

    class RecordingCycler(ScpiCycler):
        """The SCPI cycler, recording the link timeout each ``measure`` is given."""

        timeouts: list[float | None]

        def measure(self) -> Measurement:
            self.timeouts.append(self.link_timeout_s)
            return super().measure()

    server = SilentServer()
    try:
        cycler = RecordingCycler.open(f"socket://127.0.0.1:{server.port}", timeout_s=0.2, retries=0)
        cycler.timeouts = []
        calls = InstrumentCalls(retries=3, backoff_s=0.5, clock=RealClock(), stats=RunStats(), budget_s=0.35)
        with pytest.raises(Abort, match="measure failed after 2 attempts") as info:
            calls.call("measure", cycler.measure)
        cycler.close()
        assert info.value.kind == "communication" and info.value.device is cycler
        first, retry = cycler.timeouts
        assert first == 0.2 and retry is not None and MIN_RETRY_TIMEOUT_S <= retry <= 0.35 - 0.2
        assert cycler.link_timeout_s == 0.2  # restored
        assert len(server.connections) == 2  # the retry reconnected first
    finally:
        server.close()


# -- catalog --------------------------------------------------------------------------------------------------
def test_catalog_records_runs_and_steps(catalog: Catalog, tmp_path: Path) -> None:
    log = tmp_path / "run.h5"
    rid = catalog.create(
        name="p", plan={"steps": []}, plan_path=None, log_path=str(log), settings={"a": 1}, n_entries=3
    )
    catalog.step_started(
        rid, step_count=1, entry=0, step_index=1, trial=1, kind="rest", label="r", t_start=0.0, row_start=0
    )
    catalog.step_ended(
        rid, step_count=1, status="completed", ended_by="time >= 10", t_end=10.0, row_end=11, next_entry=1
    )
    catalog.step_started(
        rid, step_count=2, entry=1, step_index=2, trial=1, kind="cc", label="c", t_start=10.0, row_start=11
    )
    rec = catalog.get(rid)
    assert (rec.next_entry, rec.step_count, rec.settings) == (1, 2, {"a": 1})
    assert rec.shown_status == "interrupted"  # running, but no runner holds its lock
    lock = RunLock(log)
    lock.acquire()
    try:
        assert catalog.get(rid).shown_status == "running"
        with pytest.raises(InputError, match="another runner"):
            RunLock(log).acquire()
    finally:
        lock.release()
    catalog.mark_interrupted_steps(rid, 15)
    steps = catalog.steps(rid)
    assert [(s["status"], s["row_end"]) for s in steps] == [("completed", 11), ("interrupted", 15)]
    catalog.update(rid, status="aborted", reason="safety: voltage")
    assert [r.shown_status for r in Catalog().list()] == ["aborted"]
    with pytest.raises(InputError, match="run 99"):
        catalog.get(99)


# -- resume copy of a log -------------------------------------------------------------------------------------
def test_reopen_keeps_every_row_and_a_backup_until_the_log_is_closed(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    w = logfile.create(path, logfile.COLUMNS, {"run_id": 1})
    first = np.arange(3.0 * len(logfile.COLUMNS)).reshape(3, -1)
    w.append(first)
    w.flush()
    w.close()
    writer, old = logfile.reopen(path, {"run_id": 1, "resumes": [{"row": 3}]})
    assert old is not None and len(old) == 3
    assert logfile.backups(path) == [tmp_path / "run.interrupted-1.h5"]
    writer.append(first + 100)
    writer.close({"status": "completed"})
    data = read_log(path)
    np.testing.assert_array_equal(data.columns[logfile.COLUMNS[0]], [0, 11, 22, 100, 111, 122])
    assert data.meta["resumes"] == [{"row": 3}] and data.meta["complete"]
    assert logfile.drop_backups(path) == [tmp_path / "run.interrupted-1.h5"]
    assert logfile.backups(path) == []


def test_recover_prefers_the_most_complete_copy(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    for name, n in (("run.interrupted-1.h5", 5), ("run.h5", 2)):
        w = open_log(tmp_path / name, logfile.COLUMNS, {})
        w.append(np.ones((n, len(logfile.COLUMNS))))
        w.close()
    data = logfile.recover(path)
    assert data is not None and len(data) == 5


def test_unreadable_copies_of_a_log_are_set_aside_not_taken_for_backups(tmp_path: Path) -> None:
    path = tmp_path / "run.h5"
    w = open_log(path, logfile.COLUMNS, {})
    w.append(np.ones((4, len(logfile.COLUMNS))))
    w.close()
    stub = path.read_bytes()[:48]  # HDF5's superblock alone: a runner killed as it created the log
    (tmp_path / "run.interrupted-1.h5").write_bytes(stub)
    (tmp_path / "run.unreadable-1.h5").write_bytes(b"older")
    moved = logfile.set_aside_unreadable(path)
    assert [(a.name, b.name) for a, b, _ in moved] == [("run.interrupted-1.h5", "run.unreadable-2.h5")]
    assert "truncated: 48 bytes" in moved[0][2]
    assert (tmp_path / "run.unreadable-2.h5").read_bytes() == stub and logfile.backups(path) == []
    assert logfile.backups(path, "unreadable") == [tmp_path / "run.unreadable-1.h5", tmp_path / "run.unreadable-2.h5"]
    data = logfile.recover(path)
    assert data is not None and len(data) == 4
    assert logfile.set_aside_unreadable(path) == []


def test_log_sink_flushes_every_few_seconds_of_test_time_whatever_the_speed(tmp_path: Path) -> None:
    """On a fast clock a real second is minutes of test time: the test-time bound flushes first."""
    sink = LogSink(lambda columns, meta: logfile.create(tmp_path / "run.h5", columns, meta), flush_s=3600.0)
    sink.start(RunStart(1, logfile.COLUMNS, {}))
    flushed_at = []
    for k in range(31):  # one sample per second of test time, all within a fraction of a real second
        sink.event((float(k),) + (0.0,) * (len(logfile.COLUMNS) - 1))
        try:
            on_disk = len(read_log(tmp_path / "run.h5"))
        except InputError:  # readable from its first flush on
            on_disk = 0
        if on_disk and (not flushed_at or on_disk > flushed_at[-1][1]):
            flushed_at.append((k, on_disk))
    assert flushed_at == [(5, 6), (10, 11), (15, 16), (20, 21), (25, 26), (30, 31)]
    assert sink.flushes == 6


# -- progress display -----------------------------------------------------------------------------------------
def test_progress_display_on_a_terminal_shows_the_step_and_the_latest_sample() -> None:
    import io
    import re

    from rich.console import Console

    from battlab.lab.documents import RunStart, RunStop, StepStart
    from battlab.lab.plan import PlanEntry
    from battlab.lab.progress import ProgressDisplay
    from protocols.protocol import Rest

    buf = io.StringIO()
    shown = ProgressDisplay("plan [1]", 3, console=Console(file=buf, force_terminal=True, width=100), refresh_s=0)
    shown.start(RunStart(1, logfile.COLUMNS, {}))
    entry = PlanEntry(1, 2, 1, Rest(("time >= 10",), "rest [a]"))
    shown.step_start(StepStart(entry, 2, 0.0, 0, "rest", 10.0))
    shown.event((3600.0, 0.0, 4.0, 3.7012, -1.25, 26.5, 25.0, 2.0, 2.0, 1.0, 0.0))
    shown.stop(RunStop("completed", None))
    text = re.sub(r"\x1b\[[0-9;?]*[a-zA-Z]", "", buf.getvalue())
    for part in (
        "plan [1]",
        "2 of 3: rest [a] [rest]",
        "4 s of 10 s",
        "1.00 h",
        "V 3.7012 V",
        "I -1.250 A",
        "T 26.5 degC",
        "1 rows",
        "run completed",
    ):
        assert part in text
