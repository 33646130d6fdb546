"""Model extensions: their cost against the base model, their agreement with PyBaMM's equivalent options, and their
sensitivities against finite differences.

Run: ``python benchmarks/bench_extensions.py`` (about 5 min on 2 cores after the extensions' steppers are compiled;
the first run compiles one stepper per extension, 10–30 s each), ``--sections speed,pybamm,fd`` to choose.

1. speed: nca18650 (default mesh, error-controlled steps, no sensitivities), every extension on at the values of
   ``ON``: a 1C discharge from 100 % to the cut-off and one hour of UDDS (the library's EV-model current, repeated
   to 3600 s) from 80 %, both at 1 s samples; best CPU time (process time: the shared host's load moves wall times
   by 2×) of ``--repeat`` interleaved rounds (each variant once per round; the first round's compile is never the
   best); ratio to the base model. Target ≤ 1.3×. Even CPU times move by ±20 % on a loaded 2-core host: ratios
   below 1 are noise, not speed-ups (the step counts say what an extension costs in steps).
2. pybamm: the BPX NMC pouch cell against PyBaMM's DFN at 60 points per domain, IDAKLU rtol 1e-8, atol 1e-10, on
   charge and discharge pulses up to 3C from 60 % (isothermal): "contact resistance" (2 mΩ), one-state hysteresis on
   the negative electrode (branches U ± 10 mV, decay rate 30, h₀ = 0), "surface form": "differential" (double layer
   0.2 F m⁻²); and PyBaMM's lumped thermal model on a BPX
   file with the six activation energies changed (1C from 100 % at 10 °C), where the voltage *change* the new
   energies cause is compared (the base models' non-isothermal disagreement, 4.1 mV here, is not the extension's).
   Target ≤ 2 mV RMSE. capacity_fade against PyBaMM's reaction-limited SEI (I_side 1.5 A at 0.1 V with α 0.5, i.e.
   j0 2.7e-4 A m⁻², SEI OCP 0.4 V, no film resistance) with "current-driven" loss of active material at constant
   rates (30 %/h and 10 %/h), and at transfer coefficient 0 (a constant side current, 0.5 A).
3. fd: per extension, the worst relative 2-norm error of dV/dθ̄ of its parameters against central differences
   (step 1e-5 in θ̄, on the steps of the base run) on 20 s pulses at 2C from 60 % at 10 °C, at the ``ON`` values and
   at "off" (not double_layer's: the voltage is not differentiable at C_dl = 0). Target ≤ 1e-3.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
from pybamm_reference import (
    BPX,
    FINE,
    capacity_fade_in_pybamm,
    hysteresis_in_pybamm,
    pybamm_zoh,
    right_limits,
    udds_current,
)
from table import Row, log, print_table

import battlab
from battlab import Cell, causes, parameters
from battlab.model.extensions import CATALOG
from battlab.model.solver import Settings
from protocols import Profile

#: values that switch each extension on (a realistic size of the effect), as each cause declares them
ON = {c.key: dict(c.example) for c in causes.extended()}


def pulses(q: float, duration: float = 400.0) -> Profile:
    t = np.arange(0.0, duration + 1.0)
    phase = (t // 20.0) % 4
    return Profile(t, np.select([phase == 0, phase == 2], [-2.0 * q, 2.0 * q], 0.0))


def bpx_pulses(q: float) -> Profile:
    steps = Profile.from_segments(
        np.array([30.0, 60.0, 30.0, 60.0, 30.0, 120.0, 60.0, 210.0]),
        np.array([0.0, -2.0, 0.0, 1.0, -3.0, 0.0, 2.0, 0.0]) * q,
    )
    t = np.arange(0.0, 601.0)
    return Profile(t, steps.value_at(t))


# ---------------------------------------------------------------------------------------------------------------
def speed(args: argparse.Namespace, rows: list[Row]) -> None:
    log(f"\n== 1. speed: nca18650, no sensitivities, best CPU time of {args.repeat} interleaved rounds ==")
    base = Cell.load("nca18650")
    q = float(base["Q_nom"])
    profiles = {
        "1C discharge": (Profile.constant(-q, 4000.0, 1.0), 1.0),
        "1 h UDDS": (Profile(np.arange(0.0, 3601.0), udds_current(3600.0, 1.0)), 0.8),
    }
    runs = {"base": base, **{k: base.with_extension(k, **ON[k]) for k in CATALOG}}
    for label, (prof, soc0) in profiles.items():
        times = dict.fromkeys(runs, np.inf)
        last = {}
        # interleaved rounds (every variant once per round, best per variant) of CPU time: the host's load drifts
        for _ in range(args.repeat):
            for key, cell in runs.items():
                c0 = time.process_time()
                last[key] = battlab.simulate(cell, prof, soc0=soc0)
                times[key] = min(times[key], time.process_time() - c0)
        for key, res in last.items():
            log(f"   {label}: {key:<18} {1e3 * times[key]:7.1f} ms ({res.stats['steps']} steps, ended {res.ended_by})")
        for key in CATALOG:
            ratio = times[key] / times["base"]
            rows.append(
                Row(f"{label}: {key} / base", ratio, None, "×", "≤ 1.3", ratio <= 1.3, f"{1e3 * times[key]:.1f} ms")
            )


# ---------------------------------------------------------------------------------------------------------------
def _pybamm(path: Path, prof: Profile, soc0: float, options: dict, values: dict) -> tuple[np.ndarray, np.ndarray]:
    import pybamm

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pv = pybamm.ParameterValues.create_from_bpx(str(path), target_soc=soc0)
        pv["Current function [A]"] = pybamm_zoh(prof.t, prof.current)
        pv.update(values, check_already_exists=False)
        sim = pybamm.Simulation(
            pybamm.lithium_ion.DFN(options),
            parameter_values=pv,
            var_pts=FINE,
            solver=pybamm.IDAKLUSolver(rtol=1e-8, atol=1e-10),
        )
        q = right_limits(prof.t)
        sol = sim.solve([0.0, float(prof.t[-1])], t_interp=q)
    n = int(np.searchsorted(q, sol.t[-1], side="right"))
    return prof.t[:n], np.asarray(sol["Voltage [V]"](q[:n]))


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    n = min(a.size, b.size)
    return float(1e3 * np.sqrt(np.mean((a[:n] - b[:n]) ** 2)))


def pybamm_section(args: argparse.Namespace, rows: list[Row]) -> None:
    import pybamm

    log("\n== 2. against PyBaMM: BPX NMC pouch cell ==")
    cell = Cell.from_bpx(BPX)
    q = float(cell["Q_nom"])
    prof = bpx_pulses(q)
    iso = {"soc0": 0.6, "isothermal": True}
    base_v = battlab.simulate(cell, prof, **iso).voltage

    # contact resistance
    R_c = 0.002
    _, v_ref = _pybamm(BPX, prof, 0.6, {"contact resistance": "true"}, {"Contact resistance [Ohm]": R_c})
    v = battlab.simulate(cell.with_extension("contact_resistance", R_c=R_c), prof, **iso).voltage
    r, r0 = _rmse(v, v_ref), _rmse(base_v, v_ref)
    log(f"   contact resistance 2 mOhm, pulses: RMSE {r:.3f} mV (base model {r0:.2f} mV)")
    rows.append(Row("vs PyBaMM: contact_resistance (pulses)", r, None, "mV", "≤ 2", r <= 2.0, f"base {r0:.2f} mV"))

    # one-state hysteresis, negative electrode
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        U = pybamm.ParameterValues.create_from_bpx(str(BPX), target_soc=0.6)["Negative electrode OCP [V]"]
    M, gamma = 0.01, 30.0
    opts, vals = hysteresis_in_pybamm(U, M, gamma)
    _, v_ref = _pybamm(BPX, prof, 0.6, opts, vals)
    v = battlab.simulate(cell.with_extension("hysteresis", M_n=M, gamma_n=gamma), prof, **iso).voltage
    r, r0 = _rmse(v, v_ref), _rmse(base_v, v_ref)
    log(f"   one-state hysteresis 10 mV, pulses: RMSE {r:.3f} mV (base model {r0:.2f} mV)")
    rows.append(Row("vs PyBaMM: hysteresis (pulses)", r, None, "mV", "≤ 2", r <= 2.0, f"base {r0:.2f} mV"))

    # double layer, differential surface form
    C = 0.2
    vals = {f"{s} electrode double-layer capacity [F.m-2]": C for s in ("Negative", "Positive")}
    _, v_ref = _pybamm(BPX, prof, 0.6, {"surface form": "differential"}, vals)
    v = battlab.simulate(cell.with_extension("double_layer", C_dl_n=C, C_dl_p=C), prof, **iso).voltage
    r, r0 = _rmse(v, v_ref), _rmse(base_v, v_ref)
    log(f"   double layer 0.2 F/m2, pulses: RMSE {r:.3f} mV (base model {r0:.2f} mV)")
    rows.append(Row("vs PyBaMM: double_layer (pulses)", r, None, "mV", "≤ 2", r <= 2.0, f"base {r0:.2f} mV"))

    # SEI growth (reaction limited: Tafel in the surface potential, or a constant rate) and loss of active material
    cases = {
        "Tafel SEI + LAM": {"I_side": 1.5, "alpha_side": 0.5, "lam_n": 0.3, "lam_p": 0.1},
        "constant SEI": {"I_side": 0.5, "alpha_side": 0.0},
    }
    for label, values in cases.items():
        opts, vals = capacity_fade_in_pybamm(cell, 298.15, **values)  # the BPX file's ambient (isothermal)
        _, v_ref = _pybamm(BPX, prof, 0.6, opts, vals)
        v = battlab.simulate(cell.with_extension("capacity_fade", **values), prof, **iso).voltage
        r, r0 = _rmse(v, v_ref), _rmse(base_v, v_ref)
        log(f"   capacity fade, {label} ({values}), pulses: RMSE {r:.3f} mV (base model {r0:.2f} mV)")
        rows.append(Row(f"vs PyBaMM: capacity_fade, {label}", r, None, "mV", "≤ 2", r <= 2.0, f"base {r0:.2f} mV"))

    # lumped thermal with changed activation energies
    data = json.loads(BPX.read_text())
    changes = {
        ("Negative electrode", "Diffusivity"): ("dE_D_s_n", 10000.0),
        ("Negative electrode", "Reaction rate constant"): ("dE_k_n", -15000.0),
        ("Positive electrode", "Diffusivity"): ("dE_D_s_p", 8000.0),
        ("Positive electrode", "Reaction rate constant"): ("dE_k_p", 10000.0),
        ("Electrolyte", "Diffusivity"): ("dE_D_e", 6000.0),
        ("Electrolyte", "Conductivity"): ("dE_kappa", 8000.0),
    }
    for (section, what), (_, dE) in changes.items():
        data["Parameterisation"][section][f"{what} activation energy [J.mol-1]"] += dE
    with tempfile.TemporaryDirectory() as tmp:
        changed = Path(tmp) / "changed.json"
        changed.write_text(json.dumps(data))
        T = 283.15
        cc = Profile.constant(-q, 3000.0, 1.0)
        amb = {"Ambient temperature [K]": T, "Initial temperature [K]": T}
        _, p0 = _pybamm(BPX, cc, 1.0, {"thermal": "lumped"}, amb)
        _, p1 = _pybamm(changed, cc, 1.0, {"thermal": "lumped"}, amb)
    b0 = battlab.simulate(cell, cc, soc0=1.0, ambient=T, T0=T).voltage
    b1 = battlab.simulate(cell.with_extension("thermal", **dict(changes.values())), cc, soc0=1.0, ambient=T, T0=T)
    n = min(p0.size, p1.size, b0.size, b1.voltage.size)
    dp, db = (p1 - p0)[:n], (b1.voltage - b0)[:n]
    r = float(1e3 * np.sqrt(np.mean((db - dp) ** 2)))
    size = float(1e3 * np.sqrt(np.mean(dp**2)))
    absolute = _rmse(b1.voltage, p1)
    log(
        f"   thermal, activation energies changed, 1C at 10 degC: change RMSE {r:.3f} mV of {size:.2f} mV "
        f"(absolute {absolute:.2f} mV, the base models' non-isothermal difference)"
    )
    rows.append(
        Row(
            "vs PyBaMM: thermal dE (1C, 10 degC), change", r, None, "mV", "≤ 2", r <= 2.0, f"absolute {absolute:.2f} mV"
        )
    )


# ---------------------------------------------------------------------------------------------------------------
def fd_section(args: argparse.Namespace, rows: list[Row]) -> None:
    log("\n== 3. sensitivities against central differences (step 1e-5 in θ̄) ==")
    base = Cell.load("nca18650")
    prof = pulses(float(base["Q_nom"]))
    kw = {"soc0": 0.6, "ambient": 283.15}
    for key in CATALOG:
        for where, values in (("on", ON[key]), ("off", {})):
            if key == "double_layer" and where == "off":
                log("   double_layer (off): not differentiable at C_dl = 0 (the right limit at a current step)")
                continue
            cell = base.with_extension(key, **values)
            names = [p.qualified for p in parameters.EXTENSIONS[key]]
            res = battlab.simulate(cell, prof, sensitivities=names, **kw)
            settings = replace(Settings(), replay=res.steps)
            errs = {}
            for j, name in enumerate(names):
                tb = cell.normalised(name)
                up = battlab.simulate(cell.with_normalised(**{name: tb + 1e-5}), prof, settings=settings, **kw)
                dn = battlab.simulate(cell.with_normalised(**{name: tb - 1e-5}), prof, settings=settings, **kw)
                fd = (up.voltage - dn.voltage) / 2e-5
                if np.linalg.norm(fd) <= 1e-9:
                    continue  # no effect at "off" (a rate while the size is 0)
                errs[name.split(".")[1]] = float(np.linalg.norm(res.sensitivities[:, j] - fd) / np.linalg.norm(fd))
            worst = max(errs.values())
            log(f"   {key} ({where}): " + ", ".join(f"{k} {v:.1e}" for k, v in errs.items()))
            rows.append(Row(f"FD check: {key} ({where}), worst", worst, None, "rel", "≤ 1e-3", worst <= 1e-3))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sections", default="speed,pybamm,fd", help="comma-separated: speed, pybamm, fd")
    ap.add_argument("--repeat", type=int, default=7, help="interleaved rounds for best-of timings")
    args = ap.parse_args()
    sections = set(args.sections.split(","))
    rows: list[Row] = []
    t0 = time.perf_counter()
    log(f"bench_extensions: battlab {battlab.__version__}, Python {sys.version.split()[0]}")
    if "speed" in sections:
        speed(args, rows)
    if "pybamm" in sections:
        pybamm_section(args, rows)
    if "fd" in sections:
        fd_section(args, rows)
    print_table(f"Summary ({time.perf_counter() - t0:.0f} s in all)", rows)


if __name__ == "__main__":
    main()
