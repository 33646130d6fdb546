"""The speed rows of the model: battlab against PyBaMM's DFN side by side, interleaved, with the machine's load.

Run: ``python benchmarks/bench_speed.py`` (about 3 min on 2 shared cores), ``--rounds N`` (default 5),
``--sweep`` (also the library sweep, 738 profiles x 18 sensitivities on 2 workers: 1-3 min more),
``--sweep-limit N`` (the first N profiles of the library only).

Rows (the yardstick, PyBaMM's DFN on Chen2020 at its default mesh and IDAKLU settings, discharging at 1C from full
to its cut-off with output on a 1 s grid, is solved in every round next to battlab's runs):

1. one hour of a 1C 0.1 Hz sinusoid at 1 s samples (zero-order hold) from 50 % with all 18 sensitivities, battlab
   on nca18650 at its default mesh, divided by PyBaMM's plain 1C discharge. Target ≤ 20×.
2. battlab's 1C discharge to its cut-off on a 1 s grid (nca18650, default mesh), divided by PyBaMM's. Target ≤ 0.1×.
3. (``--sweep``) the library sweep, 738 profiles x 18 sensitivities on 2 local workers, wall time (no PyBaMM
   counterpart). Target ≤ 60 s.

Each round times every case once (best of ``--repeat`` calls, so that one preemption does not count) in the same
process, one after the other, and takes the ratios within the round; the table gives the median round and the
best, in wall and in CPU (process) time. The machine is shared: the load average before and after is printed with
the table. battlab's first call (build of the compiled model, or its load from the cache) is timed separately.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from pybamm_reference import sine_profile
from table import log


def timed(fn: Callable[[], Any], repeat: int) -> tuple[float, float, Any]:
    """Best wall and best CPU time of ``repeat`` calls [s], and the last result."""
    wall, cpu, out = [], [], None
    for _ in range(repeat):
        c0, w0 = time.process_time(), time.perf_counter()
        out = fn()
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    return min(wall), min(cpu), out


def load() -> str:
    return "load average " + ", ".join(f"{x:.2f}" for x in os.getloadavg()) + f" on {os.cpu_count()} CPUs"


def model_rows(args: argparse.Namespace) -> list[tuple[str, float, float, str]]:
    import pybamm

    import battlab
    from battlab import Cell, parameters
    from protocols import Profile

    cell = Cell.load("nca18650")
    names = list(parameters.NAMES)
    sine = sine_profile(2.7)
    one_c = Profile.constant(-2.7, 4200.0, 1.0)
    t0 = time.perf_counter()
    first = battlab.simulate(cell, one_c, soc0=1.0)
    log(
        f"battlab first call (model build or cache load): {time.perf_counter() - t0:.2f} s "
        f"(code generation + compile {first.stats['build_seconds']:.2f} s)"
    )
    sim = pybamm.Simulation(
        pybamm.lithium_ion.DFN(), parameter_values=pybamm.ParameterValues("Chen2020"), solver=pybamm.IDAKLUSolver()
    )
    t_out = np.arange(0.0, 4200.5, 1.0)
    t0 = time.perf_counter()
    sol = sim.solve([0.0, 4200.0], t_interp=t_out, initial_soc=1.0)
    log(f"PyBaMM first call (set-up + solve): {time.perf_counter() - t0:.2f} s, ends at {sol.t[-1]:.0f} s")

    def pybamm_1c() -> Any:
        return sim.solve([0.0, 4200.0], t_interp=t_out, initial_soc=1.0)

    def battlab_1c() -> battlab.Result:
        return battlab.simulate(cell, one_c, soc0=1.0)

    def battlab_sine() -> battlab.Result:
        return battlab.simulate(cell, sine, soc0=0.5, sensitivities=names)

    rounds: list[dict[str, tuple[float, float]]] = []
    for k in range(args.rounds):
        p_w, p_c, _ = timed(pybamm_1c, args.repeat)
        d_w, d_c, d = timed(battlab_1c, args.repeat)
        s_w, s_c, s = timed(battlab_sine, max(1, args.repeat // 2))
        assert s.ended_by is None and s.sensitivities.shape == (3601, 18)
        rounds.append({"pybamm": (p_w, p_c), "1c": (d_w, d_c), "sine": (s_w, s_c)})
        log(
            f"round {k + 1}: PyBaMM 1C {1e3 * p_w:.1f} ms (CPU {1e3 * p_c:.1f}); battlab 1C {1e3 * d_w:.2f} ms "
            f"(CPU {1e3 * d_c:.2f}, {d.stats['steps']} steps); sinusoid with 18 sensitivities {s_w:.3f} s "
            f"(CPU {s_c:.3f}, {s.stats['steps']} steps) | {load()}"
        )

    def ratios(case: str, i: int) -> list[float]:
        return [r[case][i] / r["pybamm"][i] for r in rounds]

    rows = []
    for case, label, target, ok in (
        ("sine", "1 h 0.1 Hz sine, 18 sensitivities / PyBaMM plain 1C", "≤ 20×", lambda r: r <= 20.0),
        ("1c", "1C discharge, 1 s grid / PyBaMM 1C", "≤ 0.1×", lambda r: r <= 0.1),
    ):
        wall, cpu = ratios(case, 0), ratios(case, 1)
        med = statistics.median(wall)
        rows.append(
            (
                label,
                med,
                min(wall),
                f"median of {len(wall)} rounds {med:.3g}× (best {min(wall):.3g}×; "
                f"CPU time {statistics.median(cpu):.3g}×); target {target} {'met' if ok(med) else 'MISSED'}",
            )
        )
    return rows


def sweep_row(args: argparse.Namespace) -> tuple[str, float, float, str]:
    from battlab import Cell
    from battlab.design.sweep import sweep
    from protocols import Library

    lib = list(Library.build())
    if args.sweep_limit:
        lib = lib[: args.sweep_limit]
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        rep = sweep(lib, Cell.load("nca18650"), Path(tmp) / "sens.h5", workers=args.workers, progress=False)
        wall = time.perf_counter() - t0
    log(
        f"sweep: {rep.computed} profiles ({rep.ok} ok, {rep.flagged} flagged, {rep.failed} failed) on "
        f"{args.workers} workers in {wall:.1f} s, {rep.cpu_seconds:.1f} s of simulation | {load()}"
    )
    ok = wall <= 60.0 or args.sweep_limit
    return (
        f"library sweep, {len(lib)} profiles x 18 sensitivities, {args.workers} workers",
        wall,
        wall,
        f"{wall:.1f} s; target ≤ 60 s {'met' if ok else 'MISSED'}"
        + (" (a part of the library)" if args.sweep_limit else ""),
    )


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5, help="interleaved rounds (default 5)")
    ap.add_argument("--repeat", type=int, default=3, help="calls per case and round, best taken (default 3)")
    ap.add_argument("--sweep", action="store_true", help="also the library sweep (738 profiles, 18 sensitivities)")
    ap.add_argument("--sweep-limit", type=int, default=0, help="sweep only the first N profiles")
    ap.add_argument("--workers", type=int, default=2, help="sweep workers (default 2)")
    ap.add_argument("--skip-model", action="store_true", help="only the sweep")
    args = ap.parse_args(argv)
    warnings.filterwarnings("ignore")
    log(f"bench_speed: {load()} at the start")
    rows = [] if args.skip_model else model_rows(args)
    if args.sweep or args.sweep_limit:
        rows.append(sweep_row(args))
    log(f"\n{load()} at the end")
    log(f"{'row':58s} {'value':>9s}  detail")
    for label, value, _, detail in rows:
        log(f"{label:58s} {value:9.3g}  {detail}")


if __name__ == "__main__":
    main()
