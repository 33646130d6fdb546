"""The runner against the virtual tester over real loopback sockets (SCPI over TCP, Watlow F4T over Modbus TCP):
a complete run, the fault matrix, limits breached mid-run, Ctrl-C and resume, repeated trials.

The virtual labs run in this process on free ports with the drivers' stand-in cell (fast); the DFN path is in
test_lab_cli.py. Times asserted are virtual (the instrument's clock), never wall-clock durations.
"""

from __future__ import annotations

import os
import signal
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from lab_helpers import plan_from, wait_until

from battlab.io.data import load_data
from battlab.io.logs import read_log
from battlab.lab import logfile
from battlab.lab.catalog import Catalog
from battlab.lab.documents import LogSink, Subscriber
from battlab.lab.engine import EngineConfig, RunEngine, RunState
from battlab.lab.limits import Envelope
from battlab.lab.logfile import COLUMNS
from battlab.lab.session import RunResult, RunSettings, resume_run, start_run
from battlab.noise import repeat_noise
from drivers.chambers.watlow_f4t import WatlowF4T
from drivers.scpi.cycler import ScpiCycler
from drivers.scpi.dialects import BATTLAB_VIRTUAL
from drivers.virtual.faults import Fault, FaultConfig
from drivers.virtual.lab import VirtualLab
from protocols.errors import InputError

PLAN = """
name = "fault matrix"
[run]
stable_hold_s = 20
[[steps]]
kind = "rest"
until = "time >= 20"
[[steps]]
kind = "cc"
current = -2.7
until = ["time >= 60", "voltage <= 3.0"]
[[steps]]
kind = "cccv"
current = 2.7
voltage = 3.62
until = ["current <= 0.3", "time >= 150"]
[[steps]]
kind = "profile"
profile = { t = [0, 10, 20, 30, 40, 50, 60], current = [5, 0, -5, 0, 5, -5, 0] }
[[steps]]
kind = "rest"
until = "time >= 20"
"""
TIME, V, I, STEP, INDEX, CYCLE = (
    "Test Time / s",
    "Voltage / V",
    "Current / A",
    "Step Count / 1",
    "Step Index / 1",
    "Cycle Count / 1",
)


#: the lab's speed for faults placed at a row: at 1000x a busy 2-core host logs a third of PLAN's 1 s samples (the
#: rest are marked gaps) and a fault at row 120 may never come; at 200x (5 ms apart) it logs nearly all of them
ROW_SPEED = 200.0


class AtRow(Subscriber):
    """Calls ``action`` once, when the ``row``-th event of the session (of step ``step``, if given) has been
    emitted. Counting within a step keeps the fault in that step when a busy host logs fewer rows before it."""

    def __init__(self, row: int, action: Callable[[], None], step: int | None = None) -> None:
        self.row, self.action, self.step, self.n = row, action, step, 0

    def event(self, row: tuple[float, ...]) -> None:
        if self.step is not None and row[COLUMNS.index(INDEX)] != self.step:
            return
        self.n += 1
        if self.n == self.row:
            self.action()


def run_on(lab: VirtualLab, plan_text: str, tmp_path: Path, *subs: Subscriber, name: str = "run.h5") -> RunResult:
    plan = plan_from(plan_text, tmp_path)
    settings = RunSettings(cycler_url=lab.cycler_url, chamber_url=lab.chamber_url)
    return start_run(plan, settings, tmp_path / name, display=False, extra_subscribers=subs)


def check_log(result: RunResult) -> dict[str, np.ndarray]:
    """The log holds every sample of the run, in time order, with the runner's columns."""
    data = read_log(result.log_path)
    assert tuple(data.columns) == COLUMNS
    assert data.meta["complete"] and data.meta["final"]["status"] == result.status
    assert len(data) == result.summary["stats"]["samples"] == data.meta["final"]["rows"]
    assert np.all(np.diff(data.t) > 0)
    return dict(data.columns)


def test_a_plan_runs_to_completion_and_every_sample_is_logged(make_lab, home: Path, tmp_path: Path) -> None:
    # the CCCV's taper is read from its rows: at ROW_SPEED a loaded host still logs them (at 1000x beside another
    # test worker it logged 4 of the CV phase's ~100)
    lab = make_lab(soc0=0.5, speed=ROW_SPEED)
    result = run_on(lab, PLAN, tmp_path)
    assert (result.status, result.reason) == ("completed", None)
    cols = check_log(result)
    assert list(np.unique(cols[INDEX])) == [1, 2, 3, 4, 5] and np.all(np.diff(cols[INDEX]) >= 0)
    cc = cols[INDEX] == 2
    np.testing.assert_allclose(cols[I][cc], -2.7, atol=0.01)
    # the CCCV holds its voltage once it gets there (runner-side regulation) and the current tapers
    step3 = np.flatnonzero(cols[INDEX] == 3)
    reached = step3[np.argmax(cols[V][step3] >= 3.62)]  # the end of the CC phase
    tail = step3[step3 > reached + 5]
    assert tail.size > 10 and np.max(np.abs(cols[V][tail] - 3.62)) < 0.005
    assert cols[I][tail][-1] < cols[I][tail][0] - 0.3
    assert np.all(np.isfinite(cols["Surface Temperature T1 / degC"]))
    q = np.concatenate([[0.0], np.cumsum(cols[I][:-1] * np.diff(cols[TIME]))]) / 3600  # the log's own hold
    np.testing.assert_allclose(cols["Net Capacity / Ah"], q, atol=1e-9)
    data = load_data(result.log_path)  # what battlab fit reads
    assert data.meta["final"]["status"] == "completed" and data.meta["identities"]["cycler"].startswith("battlab,")
    assert [s["status"] for s in data.meta["final"]["steps"]] == ["completed"] * 5
    rec = Catalog().get(result.run_id)
    assert (rec.status, rec.next_entry, rec.rows) == ("completed", 5, len(data))
    assert not lab.snapshot()["output_on"]


@pytest.mark.parametrize("chamber", ["espec", "modbus-rtu+socket"])
def test_the_other_chambers_drive_the_same_run(make_lab, home: Path, tmp_path: Path, chamber: str) -> None:
    """The Espec P-300 text protocol and the F4T with Modbus RTU framing serve the same runner."""
    lab = make_lab(soc0=0.5, espec_port=0, modbus_rtu_port=0)
    url = lab.espec_url if chamber == "espec" else lab.rtu_url
    plan = plan_from(PLAN, tmp_path)
    result = start_run(
        plan, RunSettings(cycler_url=lab.cycler_url, chamber_url=url), tmp_path / "run.h5", display=False
    )
    assert result.status == "completed", result.reason
    cols = check_log(result)
    assert np.all(np.abs(cols["Ambient Temperature / degC"] - 25.0) < 0.5)
    ident = read_log(result.log_path).meta["identities"]["chamber"]
    assert ("P-300" in ident or "ESPEC" in ident.upper()) if chamber == "espec" else "Watlow F4T" in ident


LINK_FAULTS = [
    ("scpi", Fault.DROP, FaultConfig(drop=0.02, seed=1)),
    ("scpi", Fault.LOSE_REPLY, FaultConfig(lose_reply=0.02, seed=2)),
    ("scpi", Fault.GARBLE, FaultConfig(garble=0.03, seed=3)),
    ("scpi", Fault.DELAY, FaultConfig(delay=0.05, delay_s=0.004, seed=4)),
    ("scpi", Fault.DISCONNECT, FaultConfig(disconnect=0.02, seed=5)),
    ("modbus", Fault.DROP, FaultConfig(drop=0.1, seed=6)),
    ("modbus", Fault.GARBLE, FaultConfig(garble=0.1, seed=7)),
]


@pytest.mark.parametrize(("server", "fault", "config"), LINK_FAULTS, ids=[f"{s}-{f.value}" for s, f, _ in LINK_FAULTS])
def test_transient_link_faults_are_retried_and_lose_no_sample(
    make_lab, home: Path, tmp_path: Path, server: str, fault: Fault, config: FaultConfig
) -> None:
    lab = make_lab(soc0=0.5, **{f"{server}_faults": config})
    result = run_on(lab, PLAN, tmp_path)
    injector = lab.scpi_faults if server == "scpi" else lab.modbus_faults
    assert injector.injected[fault] > 0
    assert result.status == "completed", result.reason
    cols = check_log(result)
    assert list(np.unique(cols[INDEX])) == [1, 2, 3, 4, 5]


def test_a_dead_link_aborts_cleanly_and_the_watchdog_turns_the_output_off(make_lab, home: Path, tmp_path: Path) -> None:
    lab = make_lab(soc0=0.5, speed=ROW_SPEED)
    result = run_on(lab, PLAN, tmp_path, AtRow(10, lab.cycler_server.stop, step=2))  # in the CC step
    assert result.status == "aborted"
    assert result.reason.startswith("communication: ") and "failed after 4 attempts" in result.reason
    cols = check_log(result)
    assert cols[INDEX][-1] == 2
    rec = Catalog().get(result.run_id)
    assert (rec.status, rec.reason, rec.next_entry) == ("aborted", result.reason, 1)
    shutdown = read_log(result.log_path).meta["final"]["shutdown"]
    assert not shutdown["output_off_confirmed"] and shutdown["chamber_set_point_degC"] == 25.0
    assert wait_until(lambda: not lab.snapshot()["output_on"], timeout_s=10.0)
    assert "watchdog" in lab.cycler.trips[-1].reason


def test_a_chamber_alarm_aborts_with_the_interlock_named(make_lab, home: Path, tmp_path: Path) -> None:
    lab = make_lab(soc0=0.5, speed=ROW_SPEED)
    t_alarm: list[float] = []

    def alarm() -> None:
        t_alarm.append(lab.clock.now())
        lab.trigger_chamber_alarm(3)

    result = run_on(lab, PLAN, tmp_path, AtRow(50, alarm))
    assert result.status == "aborted"  # seen by the cycler's interlock or the chamber read, whichever comes first
    assert result.reason.startswith(("protection: ", "chamber: "))
    assert "INH" in result.reason and "alarm 1" in result.reason
    trip = lab.cycler.trips[0]
    assert "interlock" in trip.reason and trip.t_s - t_alarm[0] <= 1.0
    check_log(result)
    assert Catalog().get(result.run_id).reason == result.reason


def test_cell_over_temperature_turns_the_output_off_within_a_second(make_lab, home: Path, tmp_path: Path) -> None:
    lab = make_lab(soc0=0.5, speed=ROW_SPEED)
    t_fault: list[float] = []

    def heat() -> None:
        t_fault.append(lab.clock.now())
        lab.force_cell_temperature(273.15 + 75.0)

    result = run_on(lab, PLAN, tmp_path, AtRow(50, heat))
    assert result.status == "aborted"  # seen in the sample, or in the cycler's protection state
    r = result.reason
    assert ("surface temperature 7" in r and "above the limit 50" in r) or ("OT" in r and "T 75.0 degC" in r)
    trip = lab.cycler.trips[0]  # the instrument's own trip, programmed from the envelope
    assert "over-temperature" in trip.reason and trip.t_s - t_fault[0] <= 1.0
    cols = check_log(result)
    if r.startswith("safety: "):
        assert cols["Surface Temperature T1 / degC"][-1] > 70  # the breaching sample is logged
    assert not lab.snapshot()["output_on"]


BREACH = """
name = "breach"
[run]
sample_period_s = 0.5
stable_hold_s = 5
[limits]
voltage_min = 3.3
[[steps]]
kind = "rest"
until = "time >= 5"
[[steps]]
kind = "cc"
current = -5.0
until = "time >= 3000"
"""


def test_limit_breached_mid_run_instrument_layer(make_lab, home: Path, tmp_path: Path) -> None:
    """The battlab-virtual dialect has a low-voltage cut-off: the runner programs it from the envelope."""
    lab = make_lab(soc0=0.5, speed=200.0)
    result = run_on(lab, BREACH, tmp_path)
    assert lab.cycler.voltage_limit_low == 3.3  # programmed from the envelope before the output went on
    assert result.status == "aborted"  # whichever layer saw it first: the instrument's cut-off or the sample
    if result.reason.startswith("protection: "):
        assert "VLIM-" in result.reason and "3.3 V reached on discharge" in lab.cycler.trips[0].reason
    else:
        assert result.reason.startswith("safety: voltage 3.2")
    cols = check_log(result)
    assert cols[INDEX][-1] == 2


def test_limit_breached_mid_run_runner_layer(make_lab, home: Path, tmp_path: Path) -> None:
    """A dialect without a low-voltage cut-off: the runner's own check turns the output off within 1 s.

    The lab runs at 50x, so the latency is judged in real seconds (instrument seconds / speed): in instrument time
    a busy host's 20 ms would read as a second."""
    speed = 50.0
    props = tuple(p for p in BATTLAB_VIRTUAL.properties if p.name != "voltage_limit_low")
    dialect = replace(BATTLAB_VIRTUAL, name="no-low-cutoff", properties=props)
    lab = make_lab(soc0=0.5, speed=speed, dialect=dialect)
    plan = plan_from(BREACH, tmp_path)
    cycler = ScpiCycler.open(lab.cycler_url, dialect)
    chamber = WatlowF4T.open(lab.chamber_url)
    env = Envelope(3.3, 4.25, 13.5, 13.5, 323.15)
    sink = LogSink(lambda columns, meta: logfile.create(tmp_path / "breach.h5", columns, meta))
    engine = RunEngine(plan, cycler, chamber, EngineConfig(envelope=env, clock=cycler.clock(), watchdog_s=60.0), [sink])
    try:
        assert engine.run() is RunState.ABORTED
    finally:
        cycler.close()
        chamber.close()
    assert engine.reason.startswith("safety: voltage 3.2") and "outside the limits [3.3, 4.25]" in engine.reason
    assert any("runner enforces voltage_min" in n for n in engine.stats.notes)
    assert lab.cycler.trips == []  # the instrument never tripped: the runner turned it off
    data = read_log(tmp_path / "breach.h5")
    assert len(data) == engine.stats.samples
    v, t = data.voltage, data.t + data.meta["t0_s"]
    assert v[-1] < 3.3 <= v[-2]  # the breaching sample is the last one, and it is logged
    assert engine.shutdown.output_off_confirmed
    assert engine.shutdown.output_off_sent_t_s >= t[-1]  # sent on the breaching sample, not before it
    assert (engine.shutdown.output_off_t_s - t[-1]) / speed <= 1.0  # confirmed off within 1 real second of it
    assert abs(engine.shutdown.current_after_A) < 0.05
    assert not lab.snapshot()["output_on"]


def test_ctrl_c_stops_safely_and_the_run_resumes_to_completion(make_lab, home: Path, tmp_path: Path) -> None:
    lab = make_lab(soc0=0.5, speed=ROW_SPEED)
    result = run_on(lab, PLAN, tmp_path, AtRow(120, lambda: os.kill(os.getpid(), signal.SIGINT)))
    assert result.status == "stopped" and "stopped by the operator (SIGINT)" in result.reason
    assert not lab.snapshot()["output_on"]
    first = read_log(result.log_path)
    stopped_at = int(first.columns[INDEX][-1])
    assert Catalog().get(result.run_id).shown_status == "stopped"
    resumed = resume_run(result.run_id, display=False)
    assert resumed.status == "completed", resumed.reason
    data = read_log(result.log_path)
    n = len(first)
    for col in COLUMNS:  # every row of the first session, unchanged
        np.testing.assert_array_equal(data.columns[col][:n], first.columns[col])
    assert np.all(np.diff(data.t) > 0)
    (mark,) = data.meta["interrupted"]
    assert mark["status"] == "stopped" and mark["step_index"] == stopped_at and mark["rows"][1] == n
    idx = data.columns[INDEX]
    assert idx[n] == stopped_at  # the interrupted step restarts from its beginning
    assert data.columns["Step Time / s"][n] < 1.0
    assert list(np.unique(idx[n:])) == list(range(stopped_at, 6))
    statuses = [(s["step_index"], s["status"]) for s in data.meta["final"]["steps"]]
    assert statuses.count((stopped_at, "stopped")) == 1 and statuses.count((stopped_at, "completed")) == 1
    assert Catalog().get(result.run_id).status == "completed"
    net = data.columns["Net Capacity / Ah"]  # not counted across the interruption
    assert net[n] == pytest.approx(net[n - 1], abs=1e-12) and np.all(np.isfinite(net))


def test_limits_are_checked_before_anything_is_switched_on(make_lab, home: Path, tmp_path: Path) -> None:
    lab = make_lab(soc0=0.5)
    with pytest.raises(InputError, match="step 2 .cc.: current -20 A exceeds the limit 13.5 A"):
        run_on(lab, PLAN.replace("current = -2.7", "current = -20.0"), tmp_path)
    assert Catalog().list() == [] and not (tmp_path / "run.h5").exists()
    assert lab.cycler.current == 0.0 and not lab.snapshot()["output_on"]


def test_a_chamber_alarm_before_the_start_is_a_preflight_abort(make_lab, home: Path, tmp_path: Path) -> None:
    lab = make_lab(soc0=0.5)
    lab.trigger_chamber_alarm(1)
    result = run_on(lab, PLAN, tmp_path)
    assert result.status == "aborted" and result.reason.startswith("preflight: ")
    assert not (tmp_path / "run.h5").exists()  # nothing ran, nothing logged
    assert Catalog().get(result.run_id).status == "aborted"


REPEAT = """
name = "noise trials"
[run]
repeat = 3
stable_hold_s = 5
[[steps]]
kind = "rest"
until = "time >= 300"
[[steps]]
kind = "profile"
profile = { t = [0, 20, 40, 60], current = [2.0, -2.0, 0.0, 0.0] }
"""


def test_repeated_trials_for_the_noise_model(make_lab, home: Path, tmp_path: Path) -> None:
    lab = make_lab(soc0=0.5)
    result = run_on(lab, REPEAT, tmp_path)
    assert result.status == "completed"
    cols = check_log(result)
    runs = [(int(a), int(b)) for a, b in dict.fromkeys(zip(cols[INDEX], cols[CYCLE], strict=True))]
    assert runs == [(1, 1), (2, 1), (1, 2), (2, 2), (1, 3), (2, 3)]  # each trial repeats its preparation
    trials = []
    for k in (1, 2, 3):
        m = (cols[INDEX] == 2) & (cols[CYCLE] == k)
        st, i = cols["Step Time / s"][m], cols[I][m]
        assert st[-1] + 1e-6 >= 60.0  # ends on the profile's end (its last sample may be late)
        # the logged current is the profile's, at the sample's time or up to the run's worst lateness earlier
        lag = 0.5 + result.summary["stats"]["max_late_s"]
        now, before = (np.select([x < 20, x < 40], [2.0, -2.0], 0.0) for x in (st, st - lag))
        assert np.all((np.abs(i - now) < 0.01) | (np.abs(i - before) < 0.01))
        trials.append(np.interp(np.r_[5:16, 25:36, 45:56], st, cols[V][m]))
    # the same experiment three times: the trials agree far better than the 90-180 mV current steps they contain
    assert repeat_noise(np.array(trials)) < 0.01


def test_the_in_process_tester_keeps_every_sample_of_a_drive_cycle_at_1000x(home: Path, tmp_path: Path) -> None:
    """``virtual`` URLs run the tester on a lock-step clock: at 1000x every 1 s sample of a UDDS stretch is logged
    at its scheduled time (none late, no gap, whatever the machine's load; each message to the tester takes 10 ms)
    with the current the profile applies from that sample on."""
    from protocols import Cycle, drive_profile

    udds = drive_profile(Cycle.UDDS)
    n = 300
    text = f"""
name = "udds stretch"
[run]
stable_hold_s = 20
[[steps]]
kind = "rest"
until = "time >= 10"
[[steps]]
kind = "profile"
profile = {{ t = {udds.t[: n + 1].tolist()}, current = {udds.current[: n + 1].tolist()} }}
"""
    settings = RunSettings("virtual", "virtual", speed=1000.0, soc0=0.6, physics="standin")
    assert settings.clock == "lockstep"
    result = start_run(plan_from(text, tmp_path), settings, tmp_path / "udds.h5", display=False)
    assert (result.status, result.reason) == ("completed", None)
    cols = check_log(result)
    stats = result.summary["stats"]
    assert stats["late_samples"] == 0 and stats["gaps"] == 0 and stats["max_late_s"] <= 0.05
    prof = cols[INDEX] == 2
    t = cols[TIME][prof] - cols[TIME][prof][0]
    np.testing.assert_allclose(t, np.arange(n + 1), atol=0.05)  # every sample, on the grid
    expected = np.array(udds.current[: n + 1], float)
    expected[-1] = expected[-2]  # the profile's last point ends it: its current is not applied
    np.testing.assert_allclose(cols[I][prof], expected, atol=0.01)  # measured (noisy) = programmed at the instant
