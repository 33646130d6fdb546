"""Accuracy, speed and memory of battlab's DFN–thermal model against PyBaMM, side by side, with the targets.

Run: ``python benchmarks/bench_model.py`` (about 15–25 min on 2 cores, most of it PyBaMM's exact drive-cycle
reference and cold compiles), or ``--quick`` (shorter drive cycle, fewer meshes and repeats, PyBaMM's
sensitivities capped at 60 s). ``--help`` lists the options. Prints the sections as they finish and a summary
table at the end: metric, battlab, PyBaMM, ratio, target, met?

What is compared, and how:

1. Accuracy on the BPX NMC pouch cell (``../shared/data/bpx/nmc_pouch_cell_BPX.json``, 12.5 Ah), isothermal, no film
   or contact resistance (BPX has none): PyBaMM's DFN at 60 points per domain (x_n, x_s, x_p, r_n, r_p), IDAKLU
   rtol 1e-8, atol 1e-10 (atol 1e-8 where IDAKLU fails at 1e-10, as on UDDS), against battlab at its default mesh,
   at ``Mesh.converged()`` and at candidate meshes (the first that meets 1 mV on both profiles is "the accurate
   mesh", timed in 2a). Profiles: (a) 1C discharge from 100 % to the cut-off, (b) one hour of UDDS
   (``protocols.drive_profile(Cycle.UDDS)``: the library's EV-model current, repeated to 3600 s, scaled by
   12.5/2.7 to this cell's 1C) from 80 %, 1 s samples, zero-order hold. PyBaMM gets the piecewise-constant current
   exactly, as I_0 + Σ ΔI_k H(t − t_k): PyBaMM turns every Heaviside step in t into an integration stop with
   re-initialisation (checked here against a step-by-step PyBaMM solve with the current as an input parameter:
   ``--check-zoh``). PyBaMM stores the left limit at a stop and battlab reports right limits, so PyBaMM is read at
   t_k + 1 µs. RMSE over common samples.
2. Speed (best of ``--repeat`` runs; build printed separately: battlab's code generation + compile of the
   stepper as it reports it, PyBaMM's first call − best call):
   (a) 1C discharge to cut-off without sensitivities, output every 1 s and every 10 s: battlab on nca18650
       (default mesh) vs PyBaMM's DFN on Chen2020 at its default mesh and solver settings; battlab on the BPX cell
       at the accurate mesh vs PyBaMM on the same BPX cell at its default mesh. Target: ≤ 1× PyBaMM. battlab's
       error-controlled steps (the default) beside its steps at every sample (``Settings(adaptive=False)``).
   (b) one hour of a 1C 0.1 Hz sinusoid at 1 s samples from 50 % with all 18 sensitivities on nca18650.
       Targets: ≤ 20× PyBaMM's plain 1C discharge at 1 s (2a), ≥ 100× faster than PyBaMM's run of the same hour
       with 9 sensitivities. PyBaMM (in a subprocess, time-limited by ``--pybamm-timeout``): Chen2020 with 9 input
       parameters and ``calculate_sensitivities=True``, the sinusoid as PyBaMM's usual linear Interpolant (not
       zero-order hold: cheaper for PyBaMM). The 9 (PyBaMM cannot take particle radii, and porosities or c_e0 as
       inputs change its geometry and initial state): negative/positive particle diffusivity, negative/positive
       electrode conductivity, factors on the electrolyte diffusivity and conductivity functions, the cation
       transference number, factors on the negative/positive exchange-current densities (= k_n, k_p).
   (c) pulse trains, widths 1–1000 s, 0.5C–5C, discharge from 80 %, charge from 20 %, bipolar from 50 %, each
       kept within the SOC window, voltage window 2.0–4.6 V so the trains run to their end: battlab on nca18650
       with all 18 sensitivities vs PyBaMM on Chen2020 (same C-rates, exact zero-order hold, no sensitivities)
       within a time budget. Target: battlab never fails (ends at the end or at a limit, never in the solver).
   (d) peak memory of (b) in a fresh subprocess (ru_maxrss; import-only baseline beside it). Target ≤ 500 MB.
   (e) live stepping: the virtual tester's cell (``LiveCell``) over UDDS at 1 s samples, wall and CPU time per
       sample. Target: p99 ≤ 1 ms (a quiet machine: wall time includes preemption by other processes).

The compiled stepper is cached on disk; by default this script uses a fresh cache directory so that build times
are cold compiles (``--warm-cache`` reuses ``$BATTLAB_CACHE`` or ``~/.cache/battlab``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import resource
import subprocess
import sys
import tempfile
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from pybamm_reference import (
    BPX,
    SENS9,
    WIDE,
    check_zoh,
    pulse_trains,
    pybamm_bpx,
    pybamm_zoh,
    rmse_mV,
    sine_profile,
    solve_reference,
    udds_current,
)
from table import Row, best_of, log, print_table


# ---------------------------------------------------------------------------------------------------------------
# 1. accuracy
def accuracy(args: argparse.Namespace, rows: list[Row]) -> Any:
    """Returns the accurate mesh (the first candidate within 1 mV of PyBaMM on both profiles)."""
    import battlab
    from battlab import Cell
    from battlab.model.mesh import Mesh
    from protocols import Profile

    cell = Cell.from_bpx(BPX)
    q = float(cell["Q_nom"])
    drive_s = 1200.0 if args.quick else 3600.0
    cases = {
        "1C discharge": (Profile.constant(-q, 4200.0, 1.0), 1.0),
        f"UDDS {drive_s:.0f} s": (Profile(np.arange(drive_s + 1.0), udds_current(drive_s, q / 2.7)), 0.8),
    }
    log(f"\n== 1. accuracy: BPX NMC cell ({q:g} Ah), isothermal; PyBaMM DFN 60 points/domain, rtol 1e-8 ==")
    if args.check_zoh:
        log(
            f"   PyBaMM zero-order hold (Heaviside sum) vs step-by-step solve, 120 s of UDDS: "
            f"max |dV| = {1e6 * check_zoh():.2f} uV"
        )
    refs = {}
    for name, (prof, soc0) in cases.items():
        t_ref, v_ref, wall, tol = solve_reference(prof.t, prof.current, soc0)
        refs[name] = (t_ref, v_ref)
        log(
            f"   PyBaMM reference {name} ({tol}): {wall:.1f} s, {t_ref.size} samples, ends at {t_ref[-1]:.0f} s, "
            f"V {v_ref.min():.3f}–{v_ref.max():.3f} V"
        )
        if name.startswith("UDDS") and t_ref[-1] < prof.t[-1]:
            log("   WARNING: the drive cycle hit PyBaMM's cut-off")

    def run(mesh: Mesh, name: str) -> battlab.Result:
        prof, soc0 = cases[name]
        return battlab.simulate(cell, prof, soc0=soc0, isothermal=True, mesh=mesh)

    candidates = [Mesh(), Mesh(10, 6, 10, 15, grading=0.5), Mesh(15, 8, 15, 15), Mesh(20, 10, 20, 20)]
    if args.quick:
        candidates = candidates[:2]
    conv = {name: run(Mesh.converged(), name) for name in cases}
    accurate = strict = None
    for mesh in [*candidates, Mesh.converged()]:
        errs = {}
        for name in cases:
            res = run(mesh, name)
            errs[name] = (
                rmse_mV(res.t, res.voltage, *refs[name]),
                rmse_mV(res.t, res.voltage, conv[name].t, conv[name].voltage),
                res,
            )
        label = "default" if mesh == Mesh() else ("converged" if mesh == Mesh.converged() else "candidate")
        log(
            f"   battlab {label} {mesh}: "
            + "; ".join(
                f"{n}: {e[0]:.3f} mV vs PyBaMM, {e[1]:.3f} mV vs battlab converged, ended_by {e[2].ended_by}"
                for n, e in errs.items()
            )
        )
        ok = all(e[0] <= 1.0 for e in errs.values())
        if strict is None and ok and all(e[1] <= 0.5 for e in errs.values()):
            strict = mesh
        if mesh == Mesh():
            for name, e in errs.items():
                rows.append(Row(f"RMSE {name}: default mesh vs PyBaMM converged", e[0], None, "mV", "≤ 1", e[0] <= 1.0))
                rows.append(
                    Row(f"RMSE {name}: default vs converged mesh (battlab)", e[1], None, "mV", "≤ 0.5", e[1] <= 0.5)
                )
        if mesh == Mesh.converged():
            for name, e in errs.items():
                rows.append(
                    Row(f"RMSE {name}: converged mesh vs PyBaMM converged", e[0], None, "mV", "≤ 1", e[0] <= 1.0)
                )
        if ok and accurate is None:
            accurate = mesh
            if mesh != Mesh():
                for name, e in errs.items():
                    rows.append(
                        Row(
                            f"RMSE {name}: accurate mesh {mesh_label(mesh)} vs PyBaMM",
                            e[0],
                            None,
                            "mV",
                            "≤ 1",
                            e[0] <= 1.0,
                        )
                    )
    log(f"   accurate mesh (first within 1 mV of PyBaMM on both): {accurate}")
    log(f"   first mesh also within 0.5 mV of battlab's converged mesh on both: {strict}")
    return accurate or Mesh.converged()


def mesh_label(mesh: Any) -> str:
    g = "" if mesh.grading == 1.0 else f" g{mesh.grading:g}"
    return f"({mesh.n_n},{mesh.n_s},{mesh.n_p},{mesh.n_r}{g})"


# ---------------------------------------------------------------------------------------------------------------
# 2a. speed, 1C discharge
def speed_discharge(args: argparse.Namespace, rows: list[Row], accurate: Any) -> None:
    import pybamm

    import battlab
    from battlab import Cell
    from battlab.model.mesh import Mesh
    from protocols import Profile

    log(f"\n== 2a. speed: 1C discharge to cut-off, no sensitivities (best of {args.repeat}) ==")
    nca = Cell.load("nca18650")
    bpx = Cell.from_bpx(BPX)

    def battlab_case(cell: Cell, mesh: Mesh, dt: float, settings: Any = None) -> tuple[float, float, Any]:
        q = float(cell["Q_nom"])
        prof = Profile.constant(-q, 4200.0, dt)
        kw = {"isothermal": cell is bpx, "mesh": mesh, "settings": settings}
        first = battlab.simulate(cell, prof, soc0=1.0, **kw)
        best, res = best_of(lambda: battlab.simulate(cell, prof, soc0=1.0, **kw), args.repeat)
        assert first.ended_by == res.ended_by
        # the build (code generation + compile) of this cell and mesh, whenever it happened in this process
        return best, float(first.stats.get("build_seconds", float("nan"))), res

    def pybamm_case(make: Callable[[], Any], t_end: float, dt: float, **kw: Any) -> tuple[float, float, Any]:
        t_out = np.arange(0.0, t_end + dt / 2, dt)
        t0 = time.perf_counter()
        sim = make()
        sol = sim.solve([0.0, t_end], t_interp=t_out, **kw)
        t_first = time.perf_counter() - t0
        best, sol = best_of(lambda: sim.solve([0.0, t_end], t_interp=t_out, **kw), args.repeat)
        return best, max(t_first - best, 0.0), sol

    def chen() -> Any:
        pv = pybamm.ParameterValues("Chen2020")
        return pybamm.Simulation(pybamm.lithium_ion.DFN(), parameter_values=pv, solver=pybamm.IDAKLUSolver())

    def bpx_sim() -> Any:
        return pybamm_bpx(1.0, float(bpx["Q_nom"]), None)

    from battlab.model.solver import Settings

    for dt in (1.0, 10.0):
        b, b_build, res = battlab_case(nca, Mesh(), dt)
        bf, _, resf = battlab_case(nca, Mesh(), dt, Settings(adaptive=False))
        p, p_build, sol = pybamm_case(chen, 4200.0, dt, initial_soc=1.0)
        if dt == 1.0:
            args.pybamm_1c_s = p  # the yardstick of the sinusoid with sensitivities (2b)
        log(
            f"   dt_out {dt:g} s: battlab nca18650 default mesh {1e3 * b:.1f} ms (build {b_build:.2f} s, "
            f"{res.stats.get('steps')} steps, ended {res.ended_by} at {res.t[-1]:.0f} s; steps at every sample: "
            f"{1e3 * bf:.1f} ms, {resf.stats.get('steps')} steps) | PyBaMM Chen2020 default "
            f"{1e3 * p:.1f} ms (build {p_build:.2f} s, ended {sol.termination} at {sol.t[-1]:.0f} s)"
        )
        rows.append(
            Row(
                f"1C discharge, {dt:g} s output: nca18650 vs Chen2020",
                1e3 * b,
                1e3 * p,
                "ms",
                "≤ 1×",
                b <= p,
                f"build {b_build:.2f} s vs {p_build:.2f} s; fixed steps {1e3 * bf:.1f} ms",
            )
        )
        b, b_build, res = battlab_case(bpx, accurate, dt)
        p, p_build, sol = pybamm_case(bpx_sim, 4200.0, dt)
        log(
            f"   dt_out {dt:g} s: battlab BPX {accurate} {1e3 * b:.1f} ms (build {b_build:.2f} s) | PyBaMM BPX "
            f"default mesh {1e3 * p:.1f} ms (build {p_build:.2f} s, ended at {sol.t[-1]:.0f} s)"
        )
        rows.append(
            Row(
                f"1C discharge, {dt:g} s output: BPX cell, battlab {mesh_label(accurate)}",
                1e3 * b,
                1e3 * p,
                "ms",
                "≤ 1×",
                b <= p,
                f"build {b_build:.2f} s vs {p_build:.2f} s",
            )
        )


# ---------------------------------------------------------------------------------------------------------------
# 2b. sinusoid with sensitivities
def pybamm_sens_worker(duration: float, n_solves: int, fallback: float = 600.0) -> dict[str, Any]:
    """In a subprocess: PyBaMM DFN on Chen2020 with 9 input parameters and sensitivities, 0.1 Hz 1C sinusoid from
    50 %. Prints a JSON line after every solve (the parent keeps what finished before its timeout). If the full
    profile fails, times its first ``fallback`` seconds instead (reported as such, never as the hour)."""
    import pybamm

    inputs = {
        "D_s_n": 3.3e-14,
        "D_s_p": 4e-15,
        "sigma_n": 215.0,
        "sigma_p": 0.18,
        "D_e_scale": 1.0,
        "kappa_scale": 1.0,
        "t_plus": 0.2594,
        "k_n": 1.0,
        "k_p": 1.0,
    }

    def scaled(fn: Callable[..., Any], name: str) -> Callable[..., Any]:
        return lambda *a: pybamm.InputParameter(name) * fn(*a)

    def make(t_end: float) -> tuple[Any, np.ndarray]:
        pv = pybamm.ParameterValues("Chen2020")
        for key, name in (
            ("Negative particle diffusivity [m2.s-1]", "D_s_n"),
            ("Positive particle diffusivity [m2.s-1]", "D_s_p"),
            ("Negative electrode conductivity [S.m-1]", "sigma_n"),
            ("Positive electrode conductivity [S.m-1]", "sigma_p"),
            ("Cation transference number", "t_plus"),
        ):
            pv[key] = pybamm.InputParameter(name)
        for key, name in (
            ("Electrolyte diffusivity [m2.s-1]", "D_e_scale"),
            ("Electrolyte conductivity [S.m-1]", "kappa_scale"),
            ("Negative electrode exchange-current density [A.m-2]", "k_n"),
            ("Positive electrode exchange-current density [A.m-2]", "k_p"),
        ):
            pv[key] = scaled(pv[key], name)
        t = np.arange(0.0, t_end + 1.0)
        amp = float(pv["Nominal cell capacity [A.h]"])
        pv["Current function [A]"] = pybamm.Interpolant(t, -amp * np.sin(2 * np.pi * 0.1 * t), pybamm.t)
        return pybamm.Simulation(pybamm.lithium_ion.DFN(), parameter_values=pv, solver=pybamm.IDAKLUSolver()), t

    def solve(sim: Any, t: np.ndarray) -> Any:
        return sim.solve([0.0, float(t[-1])], t_interp=t, inputs=inputs, calculate_sensitivities=True, initial_soc=0.5)

    out: dict[str, Any] = {"walls": []}
    sim, t = make(duration)
    for _ in range(n_solves):
        t1 = time.perf_counter()
        try:
            sol = solve(sim, t)
        except pybamm.SolverError as exc:
            out.update(error=str(exc).splitlines()[0][:160], failed_after=time.perf_counter() - t1)
            print(json.dumps(out), flush=True)
            break
        out["walls"].append(time.perf_counter() - t1)
        sens = sol["Voltage [V]"].sensitivities
        out.update(
            termination=sol.termination,
            t_end=float(sol.t[-1]),
            n_sens=len([k for k in sens if k != "all"]),
            maxrss_mb=maxrss_mb(),
        )
        print(json.dumps(out), flush=True)
    if "error" in out and fallback:
        sim, t = make(fallback)
        t1 = time.perf_counter()
        solve(sim, t)
        out.update(fallback={"duration": fallback, "wall": time.perf_counter() - t1}, maxrss_mb=maxrss_mb())
        print(json.dumps(out), flush=True)
    return out


def maxrss_mb() -> float:
    """Peak resident set size of this process [MB]: VmHWM, which starts afresh at exec (ru_maxrss does not: it
    carries the parent's peak across fork + exec)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return float(line.split()[1]) / 1024.0
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def run_worker(mode: str, timeout: float, **kw: Any) -> dict[str, Any] | None:
    """Run a worker of this script in a fresh process; its last JSON line, or None if it printed none in time."""
    cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", mode, "--worker-args", json.dumps(kw)]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=os.environ.copy())
        stdout, failed = proc.stdout, proc.returncode != 0
        err = (proc.stderr.strip().splitlines() or ["no output"])[-1]
    except subprocess.TimeoutExpired as exc:
        raw = exc.stdout or b""
        stdout, failed, err = raw.decode() if isinstance(raw, bytes) else raw, False, ""
    lines = [ln for ln in stdout.splitlines() if ln.startswith("{")]
    if lines:
        out = json.loads(lines[-1])
        stderr = proc.stderr if "proc" in locals() else ""
        hit = re.search(r"At t = ([0-9.eE+-]+)", stderr)
        if hit:
            out["ida_failure_t"] = float(hit.group(1))
        return out
    return {"error": err} if failed else None


def speed_sensitivities(args: argparse.Namespace, rows: list[Row]) -> None:
    import battlab
    from battlab import Cell, parameters

    log(f"\n== 2b. speed: 1 h of a 1C 0.1 Hz sinusoid at 1 s samples, sensitivities (best of {args.repeat}) ==")
    nca = Cell.load("nca18650")
    prof = sine_profile(2.7)
    names = list(parameters.NAMES)
    first = battlab.simulate(nca, prof, soc0=0.5, sensitivities=names)
    best, res = best_of(lambda: battlab.simulate(nca, prof, soc0=0.5, sensitivities=names), args.repeat)
    assert res.ended_by is None and first.sensitivities.shape == (3601, 18)
    log(
        f"   battlab nca18650, 18 sensitivities: {best:.3f} s (build {first.stats.get('build_seconds', 0):.2f} s; "
        f"{res.stats.get('steps')} steps)"
    )
    nine = [parameters.NAMES.index(n) for n in SENS9]
    best9, _ = best_of(
        lambda: battlab.simulate(nca, prof, soc0=0.5, sensitivities=[names[i] for i in nine]), args.repeat
    )
    log(f"   battlab nca18650, the same 9 as PyBaMM: {best9:.3f} s")
    p = None
    note = f"PyBaMM: Chen2020, 9 sensitivities ({', '.join(SENS9)}), linear-interpolant current"
    if args.skip_pybamm_sens:
        note += "; skipped (--skip-pybamm-sens)"
    else:
        out = run_worker("pybamm-sens", args.pybamm_timeout, duration=3600.0, n_solves=2)
        if out is None:
            note += f"; no solve finished within {args.pybamm_timeout:.0f} s"
            log(f"   PyBaMM 9 sensitivities: no solve finished within {args.pybamm_timeout:.0f} s")
        elif out.get("walls"):
            walls = out["walls"]
            p = min(walls)
            log(
                f"   PyBaMM Chen2020, {out['n_sens']} sensitivities: first call {walls[0]:.2f} s (set-up + solve), "
                + (f"second {walls[1]:.2f} s" if len(walls) > 1 else "no second call within the time limit")
                + f"; {out['termination']} at {out['t_end']:.0f} s, peak RSS {out['maxrss_mb']:.0f} MB"
            )
            if len(walls) == 1:
                note += "; PyBaMM time includes its set-up (one call within the limit)"
        else:
            where = f" at t = {out['ida_failure_t']:.1f} s" if "ida_failure_t" in out else ""
            fb = out.get("fallback")
            extra = f"; its first {fb['duration']:.0f} s take {fb['wall']:.1f} s (set-up included)" if fb else ""
            note += f"; PyBaMM FAILED{where} ({out['error'][:60]}){extra}"
            log(
                f"   PyBaMM 9 sensitivities FAILED{where} after {out.get('failed_after', 0):.1f} s: "
                f"{out['error']}{extra}"
            )
        if out is not None and "maxrss_mb" in out:
            rows.append(
                Row(
                    "peak memory, sinusoid with sensitivities (PyBaMM: 9)",
                    None,
                    out["maxrss_mb"],
                    "MB",
                    "",
                    None,
                    "PyBaMM's subprocess",
                )
            )
    rows.append(
        Row("1 h sinusoid, 18 sensitivities (PyBaMM: 9)", best, p, "s", "≥ 100× faster", p and p >= 100 * best, note)
    )
    rows.append(Row("1 h sinusoid, the same 9 sensitivities", best9, p, "s", "", None))
    one_c = getattr(args, "pybamm_1c_s", None)
    if one_c:
        log(f"   18 sensitivities / PyBaMM's plain 1C discharge at 1 s (2a): {best / one_c:.1f}×")
        rows.append(
            Row(
                "1 h sinusoid, 18 sensitivities vs PyBaMM's plain 1C at 1 s",
                best,
                one_c,
                "s",
                "≤ 20×",
                best <= 20 * one_c,
                "PyBaMM Chen2020, no sensitivities (2a)",
            )
        )


# ---------------------------------------------------------------------------------------------------------------
# 2c. pulse trains
def robustness(args: argparse.Namespace, rows: list[Row]) -> None:
    import pybamm

    import battlab
    from battlab import Cell, parameters

    widths = (
        (1.0, 10.0, 100.0, 1000.0) if args.quick else (1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0)
    )
    rates = (0.5, 1.0, 2.0, 3.0, 5.0)
    nca = Cell.load("nca18650")
    cases = pulse_trains(2.7, widths, rates)
    log(f"\n== 2c. pulse trains: {len(cases)} trains, widths {widths[0]:g}–{widths[-1]:g} s, up to 5C ==")
    fails, limits, t0 = [], 0, time.perf_counter()
    for label, prof, soc0 in cases:
        res = battlab.simulate(nca, prof, soc0=soc0, sensitivities=list(parameters.NAMES), v_limits=WIDE)
        if res.ended_by is not None and res.ended_by.startswith("solver"):
            fails.append(f"{label}: {res.ended_by}")
        elif res.ended_by is not None:
            limits += 1
    wall = time.perf_counter() - t0
    log(
        f"   battlab (18 sensitivities): {len(fails)} failed, {limits} ended at a limit, "
        f"{len(cases) - len(fails) - limits} ran to the end; {wall:.1f} s in all"
    )
    for f in fails:
        log(f"     FAILED {f}")
    # PyBaMM: Chen2020 at the same C-rates, no sensitivities, within a time budget
    p_fail, p_done, p_limit, p_fail_list = 0, 0, 0, []
    t0 = time.perf_counter()
    for label, prof, soc0 in pulse_trains(5.0, widths, rates):
        if time.perf_counter() - t0 > args.pybamm_pulse_budget:
            break
        pv = pybamm.ParameterValues("Chen2020")
        pv.update(
            {
                "Current function [A]": pybamm_zoh(prof.t, prof.current),
                "Lower voltage cut-off [V]": WIDE[0],
                "Upper voltage cut-off [V]": WIDE[1],
            }
        )
        sim = pybamm.Simulation(pybamm.lithium_ion.DFN(), parameter_values=pv, solver=pybamm.IDAKLUSolver())
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                sol = sim.solve([0.0, float(prof.t[-1])], initial_soc=soc0)
            p_limit += sol.termination != "final time"
        except Exception as exc:  # noqa: BLE001 - any solver failure counts
            p_fail += 1
            p_fail_list.append(f"{label}: {type(exc).__name__}: {str(exc).splitlines()[0][:100]}")
        p_done += 1
    log(
        f"   PyBaMM Chen2020 (no sensitivities): {p_done} of {len(cases)} run in "
        f"{time.perf_counter() - t0:.0f} s: {p_fail} failed, {p_limit} ended at a limit"
    )
    for f in p_fail_list[:10]:
        log(f"     FAILED {f}")
    rows.append(
        Row(
            "pulse trains 1–1000 s, ≤ 5C: solver failures",
            len(fails),
            p_fail,
            "count",
            "0",
            not fails,
            f"battlab {len(cases)} trains, 18 sens.; PyBaMM {p_done} trains, no sens.",
        )
    )


# ---------------------------------------------------------------------------------------------------------------
# 2d. memory
def battlab_memory_worker(sensitivities: bool) -> dict[str, Any]:
    import battlab
    from battlab import Cell, parameters

    base = maxrss_mb()
    nca = Cell.load("nca18650")
    names = list(parameters.NAMES) if sensitivities else []
    res = battlab.simulate(nca, sine_profile(2.7), soc0=0.5, sensitivities=names)
    return {
        "import_mb": base,
        "maxrss_mb": maxrss_mb(),
        "ended_by": res.ended_by,
        "shape": list(res.sensitivities.shape) if res.sensitivities is not None else None,
    }


def memory(args: argparse.Namespace, rows: list[Row]) -> None:
    log("\n== 2d. memory: peak RSS of a fresh process running 1 h with 18 sensitivities ==")
    out = run_worker("battlab-memory", 600.0, sensitivities=True)
    if out is None or "error" in out:
        log(f"   failed: {out}")
        rows.append(Row("peak memory, 1 h with 18 sensitivities", None, None, "MB", "≤ 500", False, "run failed"))
        return
    log(
        f"   battlab: peak RSS {out['maxrss_mb']:.0f} MB (after imports {out['import_mb']:.0f} MB), "
        f"sensitivities {out['shape']}"
    )
    rows.append(
        Row(
            "peak memory, 1 h with 18 sensitivities",
            out["maxrss_mb"],
            None,
            "MB",
            "≤ 500",
            out["maxrss_mb"] <= 500.0,
            f"after imports alone {out['import_mb']:.0f} MB",
        )
    )


# ---------------------------------------------------------------------------------------------------------------
# 2e. live stepping (the virtual tester's cell)
def live_steps(args: argparse.Namespace, rows: list[Row]) -> None:
    """Per-sample cost of the live cell behind the virtual tester: UDDS (the library's EV-model current) at 1 s,
    one ``LiveCell.step`` per sample, wall and CPU (thread) time per step, three passes from 80 % SOC."""
    from battlab import Cell
    from battlab.model.live import LiveCell
    from protocols import Cycle, drive_profile

    log("\n== 2e. live stepping: UDDS at 1 s samples, one LiveCell.step per sample (nca18650, default mesh) ==")
    cell = Cell.load("nca18650")
    cur = drive_profile(Cycle.UDDS).current[:-1]
    LiveCell(cell, 0.8).step(float(cur[0]), 1.0, 298.15)  # compile outside the timing
    wall, cpu = [], []
    for _ in range(3):
        live = LiveCell(cell, 0.8)
        for i in cur:
            w0, c0 = time.perf_counter(), time.thread_time()
            live.step(float(i), 1.0, 298.15)
            cpu.append(time.thread_time() - c0)
            wall.append(time.perf_counter() - w0)
    w, c = 1e3 * np.array(wall), 1e3 * np.array(cpu)
    log(
        f"   {w.size} steps: wall p50 {np.median(w):.3f} ms, p99 {np.percentile(w, 99):.3f} ms, max {w.max():.2f} ms; "
        f"CPU p50 {np.median(c):.3f} ms, p99 {np.percentile(c, 99):.3f} ms"
    )
    p99 = float(np.percentile(w, 99))
    rows.append(
        Row(
            "live step p99 (UDDS, 1 s)", p99, None, "ms", "≤ 1 ms", p99 <= 1.0, f"CPU p99 {np.percentile(c, 99):.3f} ms"
        )
    )


# ---------------------------------------------------------------------------------------------------------------
def parse(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument(
        "--quick",
        action="store_true",
        help="1200 s drive cycle, 2 candidate meshes, fewer pulse "
        "trains, 3 repeats, PyBaMM sensitivities capped at 60 s",
    )
    ap.add_argument("--repeat", type=int, default=None, help="repeats for best-of timings (default 7, quick 3)")
    ap.add_argument(
        "--sections",
        default="accuracy,speed,sens,pulses,memory,live",
        help="comma-separated subset of accuracy,speed,sens,pulses,memory,live",
    )
    ap.add_argument("--pybamm-timeout", type=float, default=None, help="s for PyBaMM's sensitivity run (120)")
    ap.add_argument("--pybamm-pulse-budget", type=float, default=None, help="s for PyBaMM's pulse trains (300)")
    ap.add_argument("--skip-pybamm-sens", action="store_true", help="do not run PyBaMM with sensitivities")
    ap.add_argument("--check-zoh", action="store_true", help="verify PyBaMM's exact zero-order hold first")
    ap.add_argument("--warm-cache", action="store_true", help="reuse the compiled-stepper cache (no cold builds)")
    ap.add_argument("--worker", help=argparse.SUPPRESS)
    ap.add_argument("--worker-args", default="{}", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    args.repeat = args.repeat or (3 if args.quick else 7)
    args.pybamm_timeout = args.pybamm_timeout or (60.0 if args.quick else 120.0)
    args.pybamm_pulse_budget = args.pybamm_pulse_budget or (60.0 if args.quick else 300.0)
    return args


def main(argv: list[str] | None = None) -> None:
    args = parse(argv)
    if args.worker:
        kw = json.loads(args.worker_args)
        fn = {"pybamm-sens": pybamm_sens_worker, "battlab-memory": battlab_memory_worker}[args.worker]
        print(json.dumps(fn(**kw)), flush=True)
        return
    warnings.filterwarnings("ignore")
    if not args.warm_cache:
        os.environ["BATTLAB_CACHE"] = tempfile.mkdtemp(prefix="battlab-bench-cache-")
    import casadi
    import pybamm

    import battlab

    log(
        f"bench_model: battlab {battlab.__version__}, PyBaMM {pybamm.__version__}, CasADi {casadi.__version__}, "
        f"numpy {np.__version__}, Python {platform.python_version()}, {os.cpu_count()} CPUs, "
        f"{platform.machine()}; stepper cache {os.environ.get('BATTLAB_CACHE', '~/.cache/battlab')}"
        f"{' (warm)' if args.warm_cache else ' (cold)'}"
    )
    sections = set(args.sections.split(","))
    rows: list[Row] = []
    t_start = time.perf_counter()
    from battlab.model.mesh import Mesh

    accurate = accuracy(args, rows) if "accuracy" in sections else Mesh()
    if "speed" in sections:
        speed_discharge(args, rows, accurate)
    if "sens" in sections:
        speed_sensitivities(args, rows)
    if "pulses" in sections:
        robustness(args, rows)
    if "memory" in sections:
        memory(args, rows)
    if "live" in sections:
        live_steps(args, rows)
    print_table(f"Summary ({time.perf_counter() - t_start:.0f} s in all; ratio = battlab / PyBaMM)", rows)


if __name__ == "__main__":
    main()
