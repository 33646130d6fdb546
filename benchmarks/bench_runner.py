"""Benchmark the experiment runner: a one-hour library profile on the DFN virtual tester, and the runner's overhead.

1. One-hour library profile (default 403: 10 s pulses, ±2 A, SOC 0.4) run by the full runner (``start_run``:
   pre-flight, step executors, safety checks, HDF5 log, catalog) on the virtual tester with battlab's DFN cell,
   over loopback sockets (SCPI cycler + Modbus TCP chamber), at each ``--speeds``; the tester runs in this process
   (threads; its clock lock-step or free-running, ``--clocks``) or is served by ``battlab virtual-tester serve`` in
   another process (free-running). A lock-step clock cannot leave a sample late: its RTF shows what the machine
   sustains instead. Printed: wall time of the profile
   step, achieved real-time factor (virtual s / wall s), samples logged vs the ideal, the sampling lateness, the
   largest gap between samples and the gaps marked in the log (over 1.5 sample periods), the wall time per sample
   inside instrument calls, and the runner's own overhead per sample (wall time outside instrument calls and
   sleeps: executors, safety checks, logging, catalog).
2. Runner overhead without instruments: the same engine on in-memory instruments whose clock jumps to each next
   sample (no sockets, no sleeping): wall time per sample is the runner's cost alone, logging included.

Targets: ≥ 1000× real time including the socket round trips; ≤ 1 ms runner overhead per sample.
Run: ``python benchmarks/bench_runner.py [--quick] [--cycle udds]``; prints a table and a JSON line.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from battlab.io.logs import read_log
from battlab.lab import virtual
from battlab.lab.catalog import Catalog
from battlab.lab.documents import CatalogSink, LogSink
from battlab.lab.engine import EngineConfig, RunEngine
from battlab.lab.limits import Envelope
from battlab.lab.logfile import create
from battlab.lab.plan import Plan, RunOptions
from battlab.lab.session import RunSettings, start_run
from drivers.defaults import ChamberDefaults, CyclerDefaults
from drivers.interfaces import CyclerCapabilities, Measurement, ProtectionState
from protocols import Library, Protocol
from protocols.protocol import ProfileStep, Rest, after

TARGET_RTF = 1000.0
TARGET_OVERHEAD_S = 1e-3


def one_hour_plan(profile_id: int, duration_s: float | None = None, cycle: str | None = None) -> Plan:
    """A rest, then library profile ``profile_id`` (or the drive cycle ``cycle``, the library's EV-model current)."""
    if cycle is not None:
        from protocols import Cycle, drive_profile

        prof = drive_profile(Cycle[cycle.upper()])
    else:
        prof = Library.build()[profile_id]
    if duration_s is not None and duration_s < prof.duration:
        from protocols import Profile

        keep = prof.t <= prof.t[0] + duration_s
        prof = Profile(prof.t[keep], prof.current[keep], id=prof.id, kind=prof.kind, soc0=prof.soc0)
    proto = Protocol(f"profile {prof.id}", (Rest((after(10.0),)), ProfileStep(prof, f"profile {prof.id}")))
    return Plan(proto, RunOptions(stable_hold_s=30.0))


@contextlib.contextmanager
def served(speed: float, physics: str = "dfn") -> Iterator[dict[str, str]]:
    """``battlab virtual-tester serve`` with the DFN cell (or the stand-in) in another process."""
    with virtual.served(
        "--speed",
        str(speed),
        "--soc0",
        "0.4",
        "--duration",
        "900",
        "--physics",
        "auto" if physics == "dfn" else "standin",
    ) as urls:
        assert ("make_cell_physics" in urls["physics"]) == (physics == "dfn"), urls["physics"]
        yield urls


def bench_profile(
    plan: Plan, speed: float, where: str, workdir: Path, physics: str = "dfn", clock: str = "lockstep"
) -> dict[str, Any]:
    out = workdir / f"run-{where}-{speed:g}-{physics}-{clock}.h5"
    with contextlib.ExitStack() as stack:
        if where == "thread":
            settings = RunSettings("virtual", "virtual", speed=speed, soc0=0.4, physics=physics, clock=clock)
        else:
            urls = stack.enter_context(served(speed, physics))
            settings = RunSettings(urls["cycler"], urls["chamber"])
        result = start_run(plan, settings, out, display=False)
    data = read_log(out)
    stats = data.meta["final"]["stats"]
    prof = data.columns["Step Index / 1"] == 2
    t = data.t[prof]
    unix = data.columns["Unix Time / s"][prof]
    wall, virtual = float(unix[-1] - unix[0]), float(t[-1] - t[0])
    duration = plan.protocol.steps[1].profile.duration
    dt = np.diff(t)
    return {
        "server": where,
        "clock": clock,
        "physics": physics,
        "speed": speed,
        "status": result.status,
        "reason": result.reason,
        "profile_virtual_s": virtual,
        "profile_wall_s": wall,
        "rtf": virtual / wall if wall > 0 else float("nan"),
        "samples": int(prof.sum()),
        "ideal_samples": int(duration / plan.options.sample_period_s) + 1,
        "max_gap_s": float(dt.max()),
        "gaps_marked": int(stats["gaps"]),
        "p99_gap_s": float(np.percentile(dt, 99)),
        "mean_late_s": stats["mean_late_s"],
        "max_late_s": stats["max_late_s"],
        "late_samples": int(stats["late_samples"]),
        "late_fraction": stats["late_samples"] / max(1, stats["samples"]),
        "io_per_sample_s": stats["io_per_sample_s"],
        "overhead_per_sample_s": stats["overhead_per_sample_s"],
        "mean_set_to_sample_s": stats["mean_set_to_sample_s"],
    }


# -- in-memory instruments: the runner alone --------------------------------------------------------------------
class JumpClock:
    """A clock that jumps to where the runner sleeps to (no waiting)."""

    speed = float("inf")

    def __init__(self) -> None:
        self.t = 0.0

    def now(self) -> float:
        return self.t

    def sleep(self, dt_s: float) -> None:
        self.t += max(0.0, dt_s)


class NullCycler(CyclerDefaults):
    name = "null cycler"
    capabilities = CyclerCapabilities(clock=True, timestamps=True, low_voltage_cutoff=True, watchdog=True)

    def __init__(self, clock: JumpClock) -> None:
        self._clock, self.i, self.last_applied_t_s = clock, 0.0, None

    def clock(self) -> JumpClock:
        return self._clock

    def identify(self) -> str:
        return "null,cycler,0,0"

    def initialize(self) -> None: ...

    def set_current(self, current_A: float) -> None:
        self.i = current_A
        self.last_applied_t_s = self._clock.t

    def output(self, on: bool) -> None: ...

    def measure(self) -> Measurement:
        return Measurement(3.7 + 0.03 * self.i, self.i, 298.15, self._clock.t)

    def set_voltage_limits(self, low_V: float | None, high_V: float) -> None: ...

    def set_current_limits(self, charge_A: float, discharge_A: float) -> None: ...

    def protection(self) -> ProtectionState:
        return ProtectionState(False)

    def errors(self) -> list[tuple[int, str]]:
        return []

    def set_watchdog(self, timeout_s: float | None) -> None: ...

    def safe_off(self) -> bool:
        return True

    def close(self) -> None: ...


class NullChamber(ChamberDefaults):
    name = "null chamber"

    def identify(self) -> str:
        return "null chamber"

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


def bench_null(plan: Plan, workdir: Path) -> dict[str, float]:
    clock = JumpClock()
    catalog = Catalog(workdir / "null.sqlite")
    run_id = catalog.create(name="null", plan={}, plan_path=None, log_path="-", settings={}, n_entries=2)
    sink = LogSink(lambda columns, meta: create(workdir / "null.h5", columns, meta), plan.options.flush_s)
    subs = [sink, CatalogSink(catalog, run_id, lambda: sink.rows)]
    env = Envelope(2.5, 4.2, 13.5, 13.5, 323.15)
    engine = RunEngine(plan, NullCycler(clock), NullChamber(), EngineConfig(envelope=env, clock=clock), subs)
    w0 = time.perf_counter()
    engine.run()
    wall = time.perf_counter() - w0
    n = engine.stats.samples
    return {"samples": n, "wall_s": wall, "per_sample_s": wall / n, "sink_per_sample_s": engine.stats.sink_wall_s / n}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="1000x only, in this process")
    ap.add_argument("--profile", type=int, default=403, help="library profile id (a one-hour profile)")
    ap.add_argument("--cycle", default=None, help="a drive cycle (udds, us06, hwfet, ...) instead of --profile")
    ap.add_argument("--speeds", type=float, nargs="+", default=[1000.0, 2000.0])
    ap.add_argument(
        "--physics",
        nargs="+",
        choices=["dfn", "standin"],
        default=["dfn", "standin"],
        help="cell physics of the virtual tester (the stand-in separates the DFN's cost)",
    )
    ap.add_argument(
        "--clocks",
        nargs="+",
        choices=["lockstep", "free"],
        default=["lockstep", "free"],
        help="clock of the in-process tester (a served tester's clock is free-running)",
    )
    args = ap.parse_args()
    plan = one_hour_plan(args.profile, cycle=args.cycle)
    what = f"drive cycle {args.cycle.upper()}" if args.cycle else f"one-hour library profile {args.profile}"
    work = Path(tempfile.mkdtemp(prefix="bench-runner-"))
    os.environ["BATTLAB_HOME"] = str(work / "home")
    runs = []
    wheres = ["thread"] if args.quick else ["thread", "process"]
    speeds = [1000.0] if args.quick else args.speeds
    print(f"{what} on the DFN virtual tester over loopback sockets (runner: start_run, 1 s sampling)")
    head = f"  {'physics':<8}{'server':<8}{'clock':<9}{'speed':>7}{'wall s':>8}{'RTF':>8}{'samples':>10}"
    head += f"{'late':>6}{'late mean s':>12}"
    print(head + f"{'late max s':>11}{'gap max s':>10}{'gaps':>6}{'io/sample':>11}{'runner/sample':>14}  status")
    physics_list = ["dfn"] if args.quick else args.physics
    combos = [(p, w, c, s) for p in physics_list for w in wheres for c in args.clocks for s in speeds]
    for physics, where, clock, speed in combos:
        if where == "process" and (physics == "standin" or clock != "free"):
            continue
        r = bench_profile(plan, speed, where, work, physics, clock)
        runs.append(r)
        print(
            f"  {physics:<8}{where:<8}{clock:<9}{speed:>7g}{r['profile_wall_s']:>8.2f}{r['rtf']:>8.0f}"
            f"{r['samples']:>5}/{r['ideal_samples']:<5}{r['late_samples']:>5}{r['mean_late_s']:>12.3f}{r['max_late_s']:>11.2f}"
            f"{r['max_gap_s']:>10.2f}{r['gaps_marked']:>6}{1e6 * r['io_per_sample_s']:>8.0f} us"
            f"{1e6 * r['overhead_per_sample_s']:>11.0f} us  {r['status']}"
        )
    null = bench_null(one_hour_plan(args.profile), work)
    print(
        f"runner alone (in-memory instruments, HDF5 log and catalog): {1e6 * null['per_sample_s']:.1f} us per "
        f"sample over {null['samples']} samples ({1e6 * null['sink_per_sample_s']:.1f} us of it in the log/catalog "
        f"sinks); target <= {1e6 * TARGET_OVERHEAD_S:.0f} us"
    )
    best = [r for r in runs if r["status"] == "completed" and r["physics"] == "dfn"]
    if best:
        rtf = (
            min(r["rtf"] for r in best if r["speed"] >= TARGET_RTF)
            if any(r["speed"] >= TARGET_RTF for r in best)
            else float("nan")
        )
        print(
            f"=> real-time factor at the 1000x target: {rtf:.0f}x ({rtf / TARGET_RTF:.2f} of the target); runner "
            f"overhead {1e6 * null['per_sample_s']:.0f} us/sample alone, "
            f"{1e6 * max(r['overhead_per_sample_s'] for r in best):.0f} us/sample at most in the live runs"
        )
    print(
        json.dumps(
            {"runs": runs, "null_runner": null, "target_rtf": TARGET_RTF, "target_overhead_s": TARGET_OVERHEAD_S}
        )
    )


if __name__ == "__main__":
    main()
