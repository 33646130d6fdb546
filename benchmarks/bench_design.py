"""Benchmark of the library sweep and the design (targets printed beside each number).

    python benchmarks/bench_design.py [--workers 2] [--limit N] [--store sens.h5 --skip-sweep]

Prints: the sweep's wall time for the library (18 voltage and temperature sensitivities per profile), its CPU
time, the peak memory summed over the sweep's processes (sampled every 0.2 s with psutil), the machine's load
during the run (other work on the machine inflates the wall time: compare wall × cores with CPU); then the design
times over all usable candidates × 18 parameters: the convex relaxation (cold: first cvxpy call in the process;
warm), the first-order algorithm, and a whole stage with its checks. Targets: sweep ≤ 300 s and ≤ 2 GB on 2 cores;
a design ≤ 2 s. PyBaMM is not run side by side here: measured on this machine it needs 15–75 s per profile with 9
sensitivities (hours for the library; bench_model.py's sensitivity section times it).
"""

from __future__ import annotations

import argparse
import contextlib
import os
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import psutil

TARGET_SWEEP_S = 60.0
TARGET_SENS_RATIO = 2.0
TARGET_MEMORY_GB = 2.0
TARGET_DESIGN_S = 2.0


class MemorySampler:
    """Peak of the summed RSS of this process and all its descendants (workers, forkserver)."""

    def __init__(self, period: float = 0.2) -> None:
        self.period, self.peak, self.loads = period, 0, []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        me = psutil.Process()
        while not self._stop.is_set():
            total = 0
            for p in [me, *me.children(recursive=True)]:
                with contextlib.suppress(psutil.Error):
                    total += p.memory_info().rss
            self.peak = max(self.peak, total)
            self.loads.append(os.getloadavg()[0])
            self._stop.wait(self.period)

    def __enter__(self) -> MemorySampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def _plain(task: tuple) -> float:
    """Seconds of one profile simulated as the sweep does (same cell, window, mesh), without sensitivities (timed
    like the sweep's per-task seconds)."""
    from battlab.design.sweep.task import _cell_from
    from battlab.simulation import simulate
    from protocols.profile import Profile

    t, current, soc0, cell_dict, cfg = task
    prof = Profile(t, current, soc0=soc0)
    cell = _cell_from(cell_dict)
    t0 = time.perf_counter()
    window = cfg.limits.window(cell)
    simulate(cell, prof, ambient=cfg.ambient, isothermal=cfg.isothermal, mesh=cfg.mesh, v_limits=window)
    return time.perf_counter() - t0


def run_plain(profs: list, cell: object, workers: int) -> tuple[float, float]:
    """Wall time [s] of the library profiles simulated without sensitivities on ``workers`` processes (the sweep
    also runs the conventional tests: the ratio slightly overstates the sensitivities' cost)."""
    from concurrent.futures import ProcessPoolExecutor

    from battlab.design.sweep import SweepConfig

    cfg = SweepConfig()
    tasks = [(p.t, p.current, p.soc0, cell.to_toml_dict(), cfg) for p in profs]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(workers) as ex:
        ex.submit(_plain, tasks[0]).result()  # the workers' start (imports, model load) is not simulation
        t0 = time.perf_counter()
        per_task = sum(ex.map(_plain, tasks, chunksize=8))
    wall = time.perf_counter() - t0
    print(f"  the same {len(profs)} profiles without sensitivities: wall {wall:.1f} s, per-task sum {per_task:.1f} s")
    return wall, per_task


def run_sweep(store: Path, workers: int, limit: int | None) -> None:
    import battlab
    from battlab.design import sweep
    from battlab.design.conventional import conventional_profiles
    from protocols import Library

    lib = Library.build()
    profs = sweep.select_profiles(lib, limit=limit)
    hours = sum(p.duration for p in profs) / 3600
    cell = battlab.Cell.load("nca18650")
    if store.exists():
        store.unlink()
    cpu0 = psutil.cpu_times()
    t0 = time.perf_counter()
    with MemorySampler() as mem:
        rep = sweep.sweep(profs, cell, store, workers=workers, conventional=conventional_profiles(), progress=False)
    wall = time.perf_counter() - t0
    cpu1 = psutil.cpu_times()
    busy = (cpu1.user - cpu0.user) + (cpu1.system - cpu0.system)
    print(
        f"sweep: {len(profs)} profiles ({hours:.1f} h of current) + {len(conventional_profiles())} conventional "
        f"tests, 18 sensitivities, {workers} workers"
    )
    print(f"  ok {rep.ok}, flagged {rep.flagged}, failed {rep.failed}")
    print(
        f"  wall {wall:.1f} s (target {TARGET_SWEEP_S:.0f} s: {'met' if wall <= TARGET_SWEEP_S else 'MISSED'}), "
        f"ratio to target {wall / TARGET_SWEEP_S:.2f}"
    )
    print(
        f"  worker CPU (sum of per-task times) {rep.cpu_seconds:.1f} s; machine CPU busy {busy:.1f} s of "
        f"{wall * psutil.cpu_count():.1f} available; load average during run "
        f"{np.mean(mem.loads):.2f} (max {np.max(mem.loads):.2f}) on {psutil.cpu_count()} cores"
    )
    print(
        f"  peak memory (all sweep processes) {mem.peak / 1e9:.2f} GB (target {TARGET_MEMORY_GB} GB: "
        f"{'met' if mem.peak / 1e9 <= TARGET_MEMORY_GB else 'MISSED'}); store {store.stat().st_size / 1e6:.0f} MB"
    )
    plain_wall, plain_tasks = run_plain(profs, cell, workers)
    from battlab.design.sweep import SensitivityStore

    with SensitivityStore.open(store) as st:
        lib_tasks = sum(float(st.info(p.id)["seconds"]) for p in profs)
    ratio = lib_tasks / plain_tasks
    print(
        f"  18 sensitivities / none, per-task seconds of the library profiles: {ratio:.2f}x (target <= "
        f"{TARGET_SENS_RATIO:.0f}x: {'met' if ratio <= TARGET_SENS_RATIO else 'MISSED'}); wall {wall / plain_wall:.2f}x"
    )


def run_design(store: Path) -> None:
    from battlab.design import firstorder, identifiability, information, relax
    from battlab.design import groups as gd
    from battlab.design.sweep import SensitivityStore

    with SensitivityStore.open(store) as s:
        t0 = time.perf_counter()
        info = information.load(s)
        conv = information.conventional(s)
        t_load = time.perf_counter() - t0
    F = info.F
    nulls = gd.null_directions(F.sum(axis=0), info.names)
    B = gd.identifiable_basis(F.sum(axis=0)) if nulls else np.eye(len(info.names))
    Fp = np.einsum("pa,lpq,qb->lab", B, F, B)
    print(
        f"design: {len(info)} usable candidates x {len(info.names)} parameters "
        f"({len(nulls)} unidentifiable directions projected out, {Fp.shape[1]} remain); load {t_load:.2f} s"
    )
    for c in ("D", "A", "E"):
        t0 = time.perf_counter()
        r = relax.solve(Fp, 5, c)
        cold = time.perf_counter() - t0
        t0 = time.perf_counter()
        r = relax.solve(Fp, 5, c)
        warm = time.perf_counter() - t0
        line = f"  {c}: cvxpy/{r.solver} cold {cold:.2f} s, warm {warm:.2f} s ({r.status})"
        if c != "E":
            t0 = time.perf_counter()
            fo = firstorder.solve(Fp, 5, c, tol=1e-9)
            line += f"; first-order {time.perf_counter() - t0:.2f} s ({fo.iterations} iterations)"
        print(line + f"  target {TARGET_DESIGN_S} s: {'met' if warm <= TARGET_DESIGN_S else 'MISSED'}")
    settings = gd.Settings(M=5, on_singular="project")
    t0 = time.perf_counter()
    d = gd.design_stage(F, info, list(info.names), settings, conventional=conv)
    print(
        f"  one stage with all checks (relaxation, first-order check, rounding + exchange, 1000 random designs, "
        f"conventional): {time.perf_counter() - t0:.2f} s; selected {d.selected}"
    )
    ranking = identifiability.rank(info.W, info.names, info.ids)
    groups = identifiability.group(ranking, 4)
    t0 = time.perf_counter()
    gd.design_groups(info, groups, settings, conv)
    print(f"  four cumulative group designs with all checks: {time.perf_counter() - t0:.2f} s")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--limit", type=int, default=None, help="only the first N library profiles")
    ap.add_argument("--store", type=Path, default=None, help="sensitivity store (default: a temporary file)")
    ap.add_argument("--skip-sweep", action="store_true", help="time the design on an existing --store only")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        store = a.store or Path(tmp) / "sens.h5"
        if not a.skip_sweep:
            run_sweep(store, a.workers, a.limit)
        run_design(store)


if __name__ == "__main__":
    main()
