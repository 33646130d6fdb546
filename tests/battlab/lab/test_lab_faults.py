"""What the runner's logs and catalog survive: a truncated log, a kill at the log's creation, stalls of the runner
(gaps marked), a dead tester (output off within a second), instruments that cannot be reached before the start.

The virtual labs run in this process on free loopback ports with the drivers' stand-in cell unless a case needs
the tester in another process. Times asserted are the instrument's (virtual) or logged ones, never wall-clock
durations, except generous bounds where a hang is the defect.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from lab_helpers import plan_from

from battlab.cli import main
from battlab.io.logged import LoggedData
from battlab.io.logs import read_log
from battlab.lab import logfile
from battlab.lab.catalog import Catalog
from battlab.lab.documents import RunStop, Subscriber
from battlab.lab.session import RunResult, RunSettings, start_run
from drivers.virtual.faults import Fault
from drivers.virtual.lab import VirtualLab

BATTLAB = [sys.executable, "-c", "from battlab.cli import main; main()"]
SHORT = """
name = "short"
[run]
stable_hold_s = 5
[[steps]]
kind = "rest"
until = "time >= 20"
[[steps]]
kind = "cc"
current = -2.7
until = "time >= 100"
"""


def run_on(lab: VirtualLab, plan_text: str, tmp_path: Path, name: str = "run.h5", **kw: object) -> RunResult:
    plan = plan_from(plan_text, tmp_path)
    settings = RunSettings(cycler_url=lab.cycler_url, chamber_url=lab.chamber_url)
    return start_run(plan, settings, tmp_path / name, display=False, **kw)


def test_a_truncated_run_log_is_one_input_error_naming_the_file(
    make_lab, home: Path, tmp_path: Path, load_in_subprocess
) -> None:
    result = run_on(make_lab(soc0=0.5), SHORT, tmp_path)
    assert result.status == "completed", result.reason
    data = result.log_path.read_bytes()
    n = len(read_log(result.log_path))
    cuts = []
    for name, size in (("superblock", 48), ("half", len(data) // 2), ("one-byte-short", len(data) - 1)):
        cut = tmp_path / f"cut-{name}.h5"
        cut.write_bytes(data[:size])
        cuts.append(cut)
    got = load_in_subprocess([result.log_path, *cuts])
    assert got[0] == {"rows": n}
    for cut, answer in zip(cuts, got[1:], strict=True):
        assert answer.get("error") == "InputError", (cut.name, answer)
        message = str(answer["message"])
        assert message.startswith(str(cut)) and "truncated" in message and "\n" not in message


#: ``battlab …`` in a child process that dies by SIGKILL the instant it creates the run log ``run.h5`` (the
#: file as HDF5 leaves it then: its 48-byte superblock, nothing else)
DIE_AT_LOG_CREATION = """
import os, signal, h5py
_File = h5py.File
class File(_File):
    def __init__(self, name, mode="r", *args, **kwargs):
        super().__init__(name, mode, *args, **kwargs)
        if mode == "w" and os.path.basename(str(name)) == "run.h5":
            os.kill(os.getpid(), signal.SIGKILL)
h5py.File = File
from battlab.cli import main
main()
"""


def test_a_kill_at_log_creation_leaves_a_log_resume_sets_aside(make_lab, home: Path, tmp_path: Path) -> None:
    lab = make_lab(soc0=0.5)
    plan, out = tmp_path / "plan.toml", tmp_path / "run.h5"
    plan.write_text(SHORT)
    env = {**os.environ, "BATTLAB_HOME": str(home)}
    args = ["run", str(plan), "--cycler", lab.cycler_url, "--chamber", lab.chamber_url, "-o", str(out), "--quiet"]
    killed = subprocess.run(
        [sys.executable, "-c", DIE_AT_LOG_CREATION, *args], env=env, capture_output=True, text=True, timeout=120
    )
    assert killed.returncode == -signal.SIGKILL, killed.stderr
    assert out.stat().st_size == 48
    listed = CliRunner().invoke(main, ["runs", "list", "--json"])
    assert listed.exit_code == 0, listed.output
    (row,) = [json.loads(line) for line in listed.output.splitlines()]
    assert row["status"] == "interrupted" and row["next_entry"] == 0

    resumed = subprocess.run(
        [*BATTLAB, "runs", "resume", str(row["id"]), "--quiet"], env=env, capture_output=True, text=True, timeout=120
    )
    assert resumed.returncode == 0, resumed.stderr
    assert "Traceback" not in resumed.stderr
    kept = tmp_path / "run.unreadable-1.h5"
    warnings = [line for line in resumed.stderr.splitlines() if str(out) in line]
    assert len(warnings) == 1 and str(kept) in warnings[0] and "first step" in warnings[0], resumed.stderr
    assert kept.stat().st_size == 48  # kept aside, unchanged
    data = read_log(out)
    assert data.meta["complete"] and data.meta["final"]["status"] == "completed"
    assert [(s["step_index"], s["status"]) for s in data.meta["final"]["steps"]] == [(1, "completed"), (2, "completed")]
    assert data.columns["Step Index / 1"][0] == 1 and data.columns["Step Time / s"][0] < 1.0
    assert not list(tmp_path.glob("run.interrupted-*.h5"))
    assert Catalog().get(row["id"]).status == "completed"


class Stall(Subscriber):
    """Stalls the runner (a blocking sleep in its one thread) for ``stalls[row]`` real seconds after that row."""

    def __init__(self, stalls: dict[int, float]) -> None:
        self.stalls, self.n = stalls, 0

    def event(self, row: tuple[float, ...]) -> None:
        self.n += 1
        if self.n in self.stalls:
            time.sleep(self.stalls[self.n])


def check_gaps_marked(data: LoggedData, period_s: float) -> list[list[float]]:
    """Every interval between consecutive rows longer than 1.5 sample periods is marked in the log, and only those;
    returns the marks ``[row after the gap, test time before, test time after]``."""
    t = data.t
    marks = data.meta["gaps"]
    rows = [int(m[0]) for m in marks]
    assert rows == [int(k) + 1 for k in np.flatnonzero(np.diff(t) > 1.5 * period_s)]
    for row, t_from, t_to in marks:
        assert (t_from, t_to) == (t[int(row) - 1], t[int(row)])
    return marks


def test_stalls_of_the_runner_leave_marked_gaps_and_the_first_row_starts_the_step(
    make_lab, home: Path, tmp_path: Path
) -> None:
    lab = make_lab(soc0=0.5, speed=200.0)
    stalls = {10: 0.025, 30: 0.04, 50: 0.06, 70: 0.03}  # real seconds: 5-12 s of test time each at 200x
    result = run_on(lab, SHORT, tmp_path, extra_subscribers=(Stall(stalls),))
    assert result.status == "completed", result.reason
    data = read_log(result.log_path)
    marks = check_gaps_marked(data, 1.0)
    gaps = [t_to - t_from for _, t_from, t_to in marks]
    print(f"gaps marked at 200x: {len(marks)}, {min(gaps):.1f}-{max(gaps):.1f} s of test time")
    assert {10, 30, 50, 70} <= {int(row) for row, _, _ in marks}  # the row after each stall starts a gap
    assert result.summary["stats"]["gaps"] == len(marks) == data.meta["final"]["stats"]["gaps"]
    assert result.summary["stats"]["max_gap_s"] == pytest.approx(max(gaps))
    # the log starts with the first step: test time and step time 0 at the first sample, the origin recorded
    assert data.t[0] == 0.0 and data.columns["Step Time / s"][0] == 0.0
    assert Catalog().get(result.run_id).t0 == data.meta["t0_s"]


# -- faults at 1x: the run stops within a second ---------------------------------------------------------------
AT_1X = """
name = "faults at 1x"
[run]
stable_hold_s = 0
[[steps]]
kind = "rest"
until = "time >= 2"
[[steps]]
kind = "cc"
current = -2.7
until = "time >= 8"
"""


class FaultAt(Subscriber):
    """At the ``row``-th event, arms ``fault`` to fire ``after_s`` real seconds later (between two samples, from
    another thread, as a real fault would); records the lab's clock at the fault and at the stop document."""

    def __init__(self, lab: VirtualLab, row: int, fault: Callable[[], None], after_s: float = 0.4) -> None:
        self.lab, self.row, self.fault, self.after_s = lab, row, fault, after_s
        self.n = 0
        self.t_fault: float | None = None
        self.t_stop: float | None = None
        self.timer: threading.Timer | None = None

    def _fire(self) -> None:
        self.t_fault = self.lab.clock.now()
        self.fault()

    def event(self, row: tuple[float, ...]) -> None:
        self.n += 1
        if self.n == self.row:
            self.timer = threading.Timer(self.after_s, self._fire)
            self.timer.start()

    def stop(self, doc: RunStop) -> None:
        self.t_stop = self.lab.clock.now()
        if self.timer is not None:
            self.timer.cancel()

    @property
    def fault_to_stop_s(self) -> float:
        assert self.t_fault is not None and self.t_stop is not None, "the fault did not fire"
        return self.t_stop - self.t_fault


def _fault_run(make_lab, tmp_path: Path, fault: str, **lab_config: object) -> tuple[RunResult, FaultAt, VirtualLab]:
    lab = make_lab(soc0=0.5, speed=1.0, **lab_config)
    actions = {
        "tester closed": lab.cycler_server.stop,  # the tester's process gone: connection closed, then refused
        "no reply": lambda: lab.scpi_faults.schedule(Fault.DROP, 10**6),  # a hung tester: nothing answers
        "chamber alarm": lambda: lab.trigger_chamber_alarm(2),
    }
    probe = FaultAt(lab, 5, actions[fault])  # in the CC step, 0.4 s after its second sample
    result = run_on(lab, AT_1X, tmp_path, extra_subscribers=(probe,))
    shutdown = result.summary["shutdown"]
    sent = shutdown["output_off_sent_t_s"] - probe.t_fault
    print(f"{fault} at 1x: output off sent {sent:.2f} s, run stopped {probe.fault_to_stop_s:.2f} s after the fault")
    assert result.status == "aborted"
    assert 0.0 < sent <= 1.0 and probe.fault_to_stop_s <= 1.0
    data = read_log(result.log_path)
    assert data.meta["final"]["status"] == "aborted" and data.meta["final"]["reason"] == result.reason
    assert data.columns["Step Index / 1"][-1] == 2 and data.t[-1] >= 3.0  # every sample up to the fault is logged
    assert Catalog().get(result.run_id).reason == result.reason
    return result, probe, lab


@pytest.mark.parametrize("fault", ["tester closed", "no reply"])
def test_a_dead_tester_stops_the_run_within_a_second_at_1x(make_lab, home: Path, tmp_path: Path, fault: str) -> None:
    result, _, _ = _fault_run(make_lab, tmp_path, fault)
    assert result.reason.startswith("communication: ") and "cycler" in result.reason


def test_a_chamber_fault_stops_the_run_within_a_second_at_1x(make_lab, home: Path, tmp_path: Path) -> None:
    """No hard-wired interlock: only the runner's own watch of the chamber sees the alarm."""
    result, _, lab = _fault_run(make_lab, tmp_path, "chamber alarm", interlock=False)
    assert result.reason.startswith("chamber: ") and "chamber alarm: alarm 1" in result.reason
    assert result.summary["shutdown"]["output_off_confirmed"] and not lab.snapshot()["output_on"]


def test_a_transient_blip_at_1x_is_survived_by_the_retry(make_lab, home: Path, tmp_path: Path) -> None:
    lab = make_lab(soc0=0.5, speed=1.0)

    def blip() -> None:  # a reply lost, then the connection dropped: two failed exchanges in a row
        lab.scpi_faults.schedule(Fault.LOSE_REPLY)
        lab.scpi_faults.schedule(Fault.DISCONNECT)

    probe = FaultAt(lab, 4, blip, after_s=0.9)
    result = run_on(lab, AT_1X, tmp_path, extra_subscribers=(probe,))
    assert result.status == "completed", result.reason
    assert lab.scpi_faults.injected[Fault.LOSE_REPLY] == 1 and lab.scpi_faults.injected[Fault.DISCONNECT] == 1
    assert result.summary["stats"]["retries"] >= 1
    data = read_log(result.log_path)
    assert [s["status"] for s in data.meta["final"]["steps"]] == ["completed", "completed"]
    check_gaps_marked(data, 1.0)


# -- instruments that cannot be reached before the run -----------------------------------------------------------
def _closed_port() -> int:
    """A loopback port nobody listens on (bound, then released)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.mark.parametrize("dead", ["cycler", "chamber", "silent cycler"])
def test_unreachable_instruments_are_one_line_exit_2_and_no_run(
    make_lab, home: Path, tmp_path: Path, dead: str
) -> None:
    """Nothing started: no catalog record, no log, no resume hint, no retry chatter from the drivers or pymodbus."""
    lab = make_lab(soc0=0.5)
    urls = {"cycler": lab.cycler_url, "chamber": lab.chamber_url}
    with contextlib.ExitStack() as stack:
        if dead == "silent cycler":  # accepts the connection, never answers (a hung instrument)
            silent = stack.enter_context(socket.socket())
            silent.bind(("127.0.0.1", 0))
            silent.listen(1)
            urls["cycler"] = f"socket://127.0.0.1:{silent.getsockname()[1]}"
        elif dead == "cycler":
            urls["cycler"] = f"socket://127.0.0.1:{_closed_port()}"
        else:
            urls["chamber"] = f"modbus-tcp://127.0.0.1:{_closed_port()}"
        plan, out = tmp_path / "plan.toml", tmp_path / "run.h5"
        plan.write_text(SHORT)
        env = {**os.environ, "BATTLAB_HOME": str(home)}
        args = ["run", str(plan), "--cycler", urls["cycler"], "--chamber", urls["chamber"], "-o", str(out), "--quiet"]
        done = subprocess.run([*BATTLAB, *args], env=env, capture_output=True, text=True, timeout=120)
    role = dead.split()[-1]
    assert done.returncode == 2, done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and done.stdout == "", done.stderr
    assert lines[0].startswith(f"error: {role} {urls[role]}: ") and "resume" not in lines[0]
    assert not out.exists() and not list(tmp_path.glob("run.h5*"))
    assert Catalog().list() == []
    if dead == "chamber":  # the failed attempts are there when asked for
        verbose = subprocess.run([*BATTLAB, *args, "--verbose"], env=env, capture_output=True, text=True, timeout=120)
        assert verbose.returncode == 2 and lines[0] in verbose.stderr
        assert "failed (attempt 1 of 2)" in verbose.stderr and "pymodbus" in verbose.stderr


def test_a_resume_with_an_unreachable_instrument_changes_nothing(make_lab, home: Path, tmp_path: Path) -> None:
    # the interrupt comes at row 30: at 200x a host shared with another test worker logs it (at 1000x a loaded host
    # dropped rows and the short plan completed first)
    lab = make_lab(soc0=0.5, speed=200.0)

    class Interrupt(Subscriber):
        def __init__(self) -> None:
            self.n = 0

        def event(self, row: tuple[float, ...]) -> None:
            self.n += 1
            if self.n == 30:
                os.kill(os.getpid(), signal.SIGINT)

    first = run_on(lab, SHORT, tmp_path, extra_subscribers=(Interrupt(),))
    assert first.status == "stopped"
    before, rows = Catalog().get(first.run_id), len(read_log(first.log_path))
    url = f"socket://127.0.0.1:{_closed_port()}"
    result = CliRunner().invoke(main, ["runs", "resume", str(first.run_id), "--cycler", url, "--quiet"])
    assert result.exit_code == 2 and result.output.strip().splitlines() == [
        f"error: cycler {url}: cannot connect: [Errno 111] Connection refused"
    ]
    after = Catalog().get(first.run_id)
    assert (after.status, after.resumes, after.settings) == (before.status, before.resumes, before.settings)
    assert len(read_log(first.log_path)) == rows and not logfile.backups(first.log_path)
    resumed = CliRunner().invoke(main, ["runs", "resume", str(first.run_id), "--quiet"])
    assert resumed.exit_code == 0, resumed.output
    assert Catalog().get(first.run_id).status == "completed"


#: rest, 20 s at a constant current, rest (``name``, ``current`` [A] to fill in)
_REST_CC_REST = """
name = "{name}"
[run]
stable_hold_s = 5
[[steps]]
kind = "rest"
until = "time >= 5"
[[steps]]
kind = "cc"
current = {current}
until = ["time >= 20", "voltage >= 4.1"]
[[steps]]
kind = "rest"
until = "time >= 5"
"""


def test_a_cell_model_failure_aborts_its_run_and_the_next_run_goes_on(
    make_lab, home: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The DFN cell's step fails to converge at 5C even in halves, with its voltage inside the limits (a model
    failure, not a limit to stop at; made here by refusing every step above 10 A). The run aborts with the output off
    and the cycler's reason; the tester stays usable and the next run on it completes (its reset clears the failure;
    the cell goes on from its last good state)."""
    from battlab.lab.virtual import make_cell_physics
    from battlab.model.live import LiveCell

    real = LiveCell._advance_once

    def no_high_rate(self: LiveCell, I_dis: float, *args: object) -> tuple[float, float, float]:
        if abs(I_dis) > 10.0:
            raise RuntimeError("cell model: step did not converge")
        return real(self, I_dis, *args)

    monkeypatch.setattr(LiveCell, "_advance_once", no_high_rate)
    lab = make_lab(make_cell_physics("nca18650"), soc0=0.5, speed=100.0)
    failed = run_on(lab, _REST_CC_REST.format(name="beyond the cell", current=-13.5), tmp_path, name="fail.h5")
    assert failed.status == "aborted" and failed.reason.startswith("protection: ")
    assert "MODEL" in failed.reason and "cell model: step did not converge" in failed.reason
    assert failed.summary["shutdown"]["output_off_confirmed"] and not lab.snapshot()["output_on"]
    ok = run_on(lab, _REST_CC_REST.format(name="a charge", current=2.7), tmp_path, name="ok.h5")
    assert (ok.status, ok.reason) == ("completed", None)
    data = read_log(ok.log_path)
    assert np.all(data.columns["Current / A"][data.columns["Step Index / 1"] == 2] > 2.6)


def test_a_current_beyond_the_cell_aborts_at_the_voltage_limit_not_as_a_model_failure(
    make_lab, home: Path, tmp_path: Path
) -> None:
    """5C at 3 % SOC is more than the DFN cell can carry: its voltage collapses through the cut-off at the step and
    its solution ends there. The run aborts on the voltage limit, as with a real cell (not as a failed cell model,
    which would leave the virtual cell latched off), and the next run on the tester completes."""
    from battlab.lab.virtual import make_cell_physics

    lab = make_lab(make_cell_physics("nca18650"), soc0=0.03, speed=100.0)
    failed = run_on(lab, _REST_CC_REST.format(name="beyond the cell", current=-13.5), tmp_path, name="fail.h5")
    assert failed.status == "aborted" and "MODEL" not in failed.reason and "cell model" not in failed.reason
    assert "voltage" in failed.reason and not lab.cycler.model_failed
    assert failed.summary["shutdown"]["output_off_confirmed"] and not lab.snapshot()["output_on"]
    ok = run_on(lab, _REST_CC_REST.format(name="a charge", current=2.7), tmp_path, name="ok.h5")
    assert (ok.status, ok.reason) == ("completed", None)
