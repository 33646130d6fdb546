"""``kill -9`` of a runner mid-run, then ``battlab runs resume``: nothing flushed is lost, the instrument's watchdog
turned the output off while the runner was dead, the interrupted step restarts from its beginning with its partial
data kept and marked, and the log is complete and continuous.

The virtual tester runs in ANOTHER process (``battlab virtual-tester serve`` on free loopback ports), so its clock
and its watchdog keep running while the runner is dead, as a real bench's would.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from lab_helpers import wait_until

from battlab.io.data import load_data
from battlab.io.logs import read_log
from battlab.lab import virtual
from battlab.lab.catalog import Catalog
from battlab.lab.logfile import COLUMNS
from battlab.lab.session import watchdog_for
from drivers.scpi.cycler import ScpiCycler
from protocols.errors import InputError

SPEED = 200.0
PLAN = """
name = "kill and resume"
[run]
stable_hold_s = 10
[[steps]]
kind = "rest"
until = "time >= 60"
[[steps]]
kind = "cc"
current = -2.7
until = ["time >= 300", "voltage <= 3.0"]
[[steps]]
kind = "rest"
until = "time >= 60"
[[steps]]
kind = "cccv"
current = 2.7
voltage = 3.6
until = ["current <= 0.3", "time >= 900"]
[[steps]]
kind = "profile"
profile = { t = [0, 60, 120, 180, 240, 300], current = [3.0, 0.0, -3.0, 0.0, 1.5, 0.0] }
"""
BATTLAB = [sys.executable, "-c", "from battlab.cli import main; main()"]


@pytest.fixture
def tester() -> Iterator[dict[str, str]]:
    """``battlab virtual-tester serve`` in its own process; its URLs."""
    with virtual.served("--speed", str(SPEED), "--physics", "standin", "--duration", "300") as urls:
        yield urls


def _rows(path: Path) -> int:
    try:
        return len(read_log(path))
    except (InputError, OSError, KeyError):
        return 0


def test_kill_9_mid_run_then_resume(tester: dict[str, str], home: Path, tmp_path: Path) -> None:
    plan, out = tmp_path / "plan.toml", tmp_path / "run.h5"
    plan.write_text(PLAN)
    env = {**os.environ, "BATTLAB_HOME": str(home)}
    cmd = [
        *BATTLAB,
        "run",
        str(plan),
        "--cycler",
        tester["cycler"],
        "--chamber",
        tester["chamber"],
        "-o",
        str(out),
        "--quiet",
    ]
    # the tester's clock, tracked here without further I/O (a query at the kill would feed its watchdog)
    probe = ScpiCycler.open(tester["cycler"])
    clock = probe.clock()
    probe.close()
    runner = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        # kill it in the CCCV step (step 4), well after the start and before the end
        def in_step_4() -> bool:
            if not out.exists():
                return False
            try:
                return bool(np.any(read_log(out).columns["Step Index / 1"] == 4))
            except (InputError, OSError, KeyError):
                return False

        assert wait_until(in_step_4, timeout_s=120.0, poll_s=0.05), runner.communicate(timeout=5)
        first = _rows(out)
        # a flush more into the step: the kill then lands after rows of step 4 were written and seen here
        assert wait_until(lambda: _rows(out) > first, timeout_s=120.0, poll_s=0.05), runner.communicate(timeout=5)
        seen = read_log(out)
        t_kill = clock.now()
        runner.send_signal(signal.SIGKILL)
        runner.wait(10)
    finally:
        if runner.poll() is None:
            runner.kill()
            runner.wait(5)
    assert runner.returncode == -signal.SIGKILL
    before = read_log(out)  # what survived the kill (SWMR): the rows flushed until then
    n = len(before)
    assert not before.meta["complete"] and n > 0 and before.columns["Step Index / 1"][-1] == 4
    assert n >= len(seen) > first  # every row seen flushed before the kill survived it, unchanged
    for col in COLUMNS:
        np.testing.assert_array_equal(before.columns[col][: len(seen)], seen.columns[col])
    # test time lost at the kill (information, not asserted: it depends on the host's speed): the run clock at the
    # kill minus the last logged test time
    print(f"kill -9 at {SPEED:g}x: {(t_kill - before.meta['t0_s']) - before.t[-1]:.2f} s of test time lost")
    (rec,) = Catalog().list()
    assert rec.shown_status == "interrupted" and rec.next_entry == 3

    # the runner is dead; the instrument's watchdog turns the output off. No I/O meanwhile: a query would reset it.
    time.sleep(2 * watchdog_for(SPEED) / SPEED)
    probe = ScpiCycler.open(tester["cycler"])
    try:
        state = probe.protection()
        assert state.tripped and "WDOG" in state.causes
        assert not probe.get("output")
    finally:
        probe.close()

    resumed = subprocess.run(
        [*BATTLAB, "runs", "resume", str(rec.id), "--quiet"], env=env, capture_output=True, text=True, timeout=300
    )
    assert resumed.returncode == 0, resumed.stderr
    assert f"run {rec.id} completed" in resumed.stdout

    data = load_data(out)  # checked as battlab fit checks it
    cols = data.columns
    assert data.meta["complete"] and data.meta["final"]["status"] == "completed"
    assert len(data) > n
    for col in COLUMNS:  # no flushed sample lost, none changed
        np.testing.assert_array_equal(cols[col][:n], before.columns[col])
    t = data.t
    assert np.all(np.diff(t) > 0)  # continuous in time: one clock, one origin
    # the interrupted attempt of step 4 is kept and marked; step 4 then restarts from its beginning
    (mark,) = data.meta["interrupted"]
    assert mark["step_index"] == 4 and mark["status"] == "interrupted" and mark["rows"] == [mark["rows"][0], n]
    a = mark["rows"][0]
    assert np.all(cols["Step Index / 1"][a:n] == 4) and np.all(cols["Step Count / 1"][a:n] == mark["step_count"])
    assert cols["Step Index / 1"][n] == 4 and cols["Step Count / 1"][n] == mark["step_count"] + 1
    assert cols["Step Time / s"][n] < 1.0
    gap = t[n] - t[n - 1]
    assert gap > 60.0  # the outage (kill → resume) is the one long gap, at the mark
    assert np.sum(np.diff(t) > 60.0) == 1
    # every gap in sampling is marked, the outage and any stall of either session (marks copied on resume)
    assert [int(m[0]) for m in data.meta["gaps"]] == [int(k) + 1 for k in np.flatnonzero(np.diff(t) > 1.5)]
    assert [n, t[n - 1], t[n]] in data.meta["gaps"]
    steps = data.meta["final"]["steps"]
    assert [(s["step_index"], s["status"]) for s in steps] == [
        (1, "completed"),
        (2, "completed"),
        (3, "completed"),
        (4, "interrupted"),
        (4, "completed"),
        (5, "completed"),
    ]
    (resume,) = data.meta["resumes"]
    assert resume["row"] == n and resume["previous_status"] == "interrupted"
    assert Catalog().get(rec.id).status == "completed"
    assert not list(tmp_path.glob("run.interrupted-*.h5"))  # the backup went once the log closed cleanly
