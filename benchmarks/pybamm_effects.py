"""Logged data with one hidden effect made by PyBaMM (a model battlab did not write), for ``battlab diagnose``.

Each case is PyBaMM's DFN with lumped (here adiabatic: the BPX file has no heat transfer coefficient) thermal model
on the BPX NMC pouch cell (``pybamm.ParameterValues.create_from_bpx``), with one of PyBaMM's own options switched
on: contact resistance, one-state hysteresis (Axen et al.), a differential surface form (double layer), changed
activation energies, an SEI side reaction; and the plain DFN (null). The profile (:func:`profile`, 50 min at 1 s)
has discharge and charge pulses each followed by a rest, and two stretches of the UDDS drive cycle. The current
reaches PyBaMM exactly: a sum of Heaviside steps, which PyBaMM turns into integration stops at every switch; its
"Discharge capacity [A.h]" is checked against the integral of the current. The logged voltage, current and
temperature carry the virtual tester's physical noise (:class:`drivers.virtual.noise.NoiseModel`) and are written
as BDF CSV (:func:`battlab.io.bdf.write_bdf_csv`) with the start SOC in the sidecar.

Used by tests/battlab/diagnose/test_diagnose_pybamm.py; ``python benchmarks/pybamm_effects.py`` runs every case
through ``battlab diagnose`` and prints a table.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from pybamm_reference import hysteresis_in_pybamm, pybamm_zoh

ROOT = Path(__file__).resolve().parents[1]
BPX = Path(os.environ.get("BATTLAB_DATA", ROOT.parent / "shared" / "data")) / "bpx" / "nmc_pouch_cell_BPX.json"
#: PyBaMM's mesh points per domain and IDAKLU tolerances (converged well below the noise, see the null case)
VAR_PTS = {k: 20 for k in ("x_n", "x_s", "x_p", "r_n", "r_p")}
RTOL, ATOL = 1e-6, 1e-8
#: the tester reads the voltage this long [s] after it sets a sample's current: PyBaMM's solution is read there. For
#: every case but the double layer this is battlab's right limit (nothing else relaxes within milliseconds: the
#: voltage moves by microvolts); 1 µs after a step a double layer still holds the old overpotential (up to 170 mV
#: off on these pulses), which no tester at 1 s would log.
READ = 0.01
SOC0 = 0.7
AMBIENT_K = 298.15
#: the cell's cooling [W m⁻² K⁻¹] (natural convection; the BPX file itself gives none, i.e. adiabatic)
H_COOL = 10.0


def cell_file(folder: str | Path, activation: dict[tuple[str, str], float] | None = None) -> Path:
    """The BPX cell cooled by :data:`H_COOL` at :data:`AMBIENT_K` (BPX's State section), with activation energies
    changed by ``activation`` [J/mol]: the file PyBaMM is fed and battlab diagnoses with (``activation`` unset)."""
    data = json.loads(BPX.read_text())
    # the file is BPX 0.1, whose reader synthesises a State section of its own: write it as BPX 1.0 with one
    cell, electrolyte = data["Parameterisation"]["Cell"], data["Parameterisation"]["Electrolyte"]
    cell.pop("Thermal conductivity [W.m-1.K-1]", None)
    data["Header"]["BPX"] = "1.0.0"
    data["State"] = {
        "Initial conditions": {
            "Initial temperature [K]": AMBIENT_K,
            "Initial state-of-charge": 1.0,
            "Initial electrolyte concentration [mol.m-3]": electrolyte.pop("Initial concentration [mol.m-3]"),
        },
        "Thermal environment": {"Ambient temperature [K]": AMBIENT_K, "Heat transfer coefficient [W.m-2.K-1]": H_COOL},
    }
    cell.pop("Initial temperature [K]")
    cell.pop("Ambient temperature [K]")
    for (section, what), dE in (activation or {}).items():
        data["Parameterisation"][section][f"{what} activation energy [J.mol-1]"] += dE
    path = Path(folder) / ("nmc_pouch_cooled.json" if not activation else "nmc_pouch_cooled_changed.json")
    path.write_text(json.dumps(data, indent=1))
    return path


@dataclass(frozen=True)
class Case:
    """One hidden effect: PyBaMM ``options`` and parameter ``values`` (callables get PyBaMM's BPX parameter
    values and return the values), BPX ``activation`` changes [J/mol] and a one-line description of its size."""

    name: str
    cause: str | None  # the battlab catalog key that describes it (None: no effect)
    size: str
    options: dict[str, Any] = field(default_factory=dict)
    values: Any = None
    activation: dict[tuple[str, str], float] = field(default_factory=dict)


#: the SEI parameters PyBaMM's reaction-limited model reads (Chen 2020's set, which the BPX file has not)
SEI = {
    "Ratio of lithium moles to SEI moles": 2.0,
    "SEI partial molar volume [m3.mol-1]": 9.585e-05,
    "SEI resistivity [Ohm.m]": 200000.0,
    "SEI open-circuit potential [V]": 0.4,
    "Initial SEI thickness [m]": 5e-09,
    "SEI growth activation energy [J.mol-1]": 0.0,
}


def _hysteresis(pv: Any) -> dict[str, Any]:
    return hysteresis_in_pybamm(pv["Negative electrode OCP [V]"], 0.010, 30.0)[1]


CASES: dict[str, Case] = {
    c.name: c
    for c in (
        Case("null", None, "PyBaMM's plain DFN"),
        Case(
            "contact_resistance",
            "contact_resistance",
            "R_c 2 mOhm (about 15 % of the cell's 1 s resistance)",
            {"contact resistance": "true"},
            lambda pv: {"Contact resistance [Ohm]": 0.002},
        ),
        Case(
            "hysteresis",
            "hysteresis",
            "negative electrode one-state hysteresis: U -/+ 10 mV, decay rate 30, h0 = 0",
            {"open-circuit potential": ("one-state hysteresis", "single")},
            _hysteresis,
        ),
        Case(
            "double_layer",
            "double_layer",
            "differential surface form, 0.2 F/m2 in both electrodes",
            {"surface form": "differential"},
            lambda pv: {f"{s} electrode double-layer capacity [F.m-2]": 0.2 for s in ("Negative", "Positive")},
        ),
        Case(
            "thermal",
            "thermal",
            "activation energies changed: D_s_n +10, k_n -15, D_s_p +8, k_p +10, D_e +6, kappa +8 kJ/mol",
            activation={
                ("Negative electrode", "Diffusivity"): 10000.0,
                ("Negative electrode", "Reaction rate constant"): -15000.0,
                ("Positive electrode", "Diffusivity"): 8000.0,
                ("Positive electrode", "Reaction rate constant"): 10000.0,
                ("Electrolyte", "Diffusivity"): 6000.0,
                ("Electrolyte", "Conductivity"): 8000.0,
            },
        ),
        Case(
            "capacity_fade",
            "capacity_fade",
            "reaction-limited SEI, j0 3e-4 A/m2 (1.0 Ah of lithium lost in 50 min, 8 % of the cell)",
            {"SEI": "reaction limited", "SEI film resistance": "none"},
            lambda pv: {**SEI, "SEI reaction exchange current density [A.m-2]": 3e-4},
        ),
    )
}


# ---------------------------------------------------------------------------------------------------------------
def profile(q: float) -> Any:
    """50 min at 1 s for a cell of ``q`` [Ah]: rest, pulses at 1-2C (discharge and charge, each followed by a
    3 min rest), 10 min of UDDS, pulses up to 3C with rests, 5 min of UDDS, a final rest. UDDS is scaled as the
    library's current for a 2.7 Ah cell (same C-rates). Positive = charge."""
    from protocols import Cycle, Profile, drive_profile

    seg = [
        (60.0, 0.0),
        (60.0, -2.0),
        (180.0, 0.0),
        (60.0, 2.0),
        (180.0, 0.0),
        (120.0, -1.0),
        (180.0, 0.0),
        (120.0, 1.0),
        (180.0, 0.0),
    ]
    udds = drive_profile(Cycle.UDDS).current[:-1] * q / 2.7
    parts = [np.repeat([c * q for _, c in seg], [int(d) for d, _ in seg])]
    parts.append(udds[:600])
    seg2 = [
        (60.0, -2.0),
        (180.0, 0.0),
        (60.0, 2.0),
        (180.0, 0.0),
        (30.0, -3.0),
        (180.0, 0.0),
        (30.0, 3.0),
        (150.0, 0.0),
    ]
    parts.append(np.repeat([c * q for _, c in seg2], [int(d) for d, _ in seg2]))
    parts.append(udds[600:900])
    parts.append(np.zeros(120))
    cur = np.concatenate(parts)
    cur = np.append(cur, cur[-1])  # the last sample has no duration
    return Profile(np.arange(cur.size, dtype=float), cur, id="pulses+udds", soc0=SOC0)


@dataclass
class Truth:
    """PyBaMM's solution at the samples (right limits): time [s], voltage [V], current [A, + = charge],
    cell temperature [K]; the largest gap between PyBaMM's discharge capacity and the current's integral [Ah];
    wall time [s]."""

    t: np.ndarray
    voltage: np.ndarray
    current: np.ndarray
    temperature: np.ndarray
    charge_error_Ah: float
    seconds: float
    lithium_lost_Ah: float = 0.0


def solve(case: Case, prof: Any, soc0: float = SOC0, ambient: float = AMBIENT_K) -> Truth:
    """PyBaMM's DFN with lumped thermal model and ``case``'s effect on ``prof`` from ``soc0`` at ``ambient`` [K]."""
    import pybamm

    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        path = cell_file(tmp, case.activation)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            pv = pybamm.ParameterValues.create_from_bpx(str(path), target_soc=soc0)
    pv["Current function [A]"] = pybamm_zoh(prof.t, prof.current)
    pv.update({"Ambient temperature [K]": ambient, "Initial temperature [K]": ambient})
    if case.values is not None:
        pv.update(case.values(pv), check_already_exists=False)
    model = pybamm.lithium_ion.DFN({"thermal": "lumped", **case.options})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = pybamm.Simulation(
            model, parameter_values=pv, var_pts=VAR_PTS, solver=pybamm.IDAKLUSolver(rtol=RTOL, atol=ATOL)
        )
        q = np.concatenate([[prof.t[0]], prof.t[1:-1] + READ, [prof.t[-1]]])
        sol = sim.solve([float(prof.t[0]), float(prof.t[-1])], t_interp=q)
    n = int(np.searchsorted(q, sol.t[-1], side="right"))
    if n < prof.t.size:
        raise RuntimeError(f"PyBaMM ({case.name}) stopped at {sol.t[-1]:.0f} s of {prof.t[-1]:.0f} s")
    t, i = prof.t, prof.current
    # discharge capacity [Ah] at the read times (READ after each sample's current is set)
    q_int = (np.concatenate([[0.0], np.cumsum(-i[:-1] * np.diff(t))]) - i * (q - t)) / 3600.0
    q_pb = np.asarray(sol["Discharge capacity [A.h]"](q))
    lost = 0.0
    if "SEI" in case.options:
        # PyBaMM's loss variables are per electrode pair: the cell's is the number of pairs in parallel times it
        pairs = float(pv["Number of electrodes connected in parallel to make a cell"])
        lost = pairs * float(sol["Loss of capacity to negative SEI [A.h]"](q)[-1])
    return Truth(
        t,
        np.asarray(sol["Voltage [V]"](q)),
        i,
        np.asarray(sol["Volume-averaged cell temperature [K]"](q)),
        float(np.max(np.abs(q_pb - q_int))),
        time.perf_counter() - t0,
        lost,
    )


def logged(truth: Truth, seed: int = 7) -> dict[str, np.ndarray]:
    """What the virtual tester would log: voltage, current and temperature readings with its physical noise
    (white, current-dependent, sampling jitter × dV/dt clipped to the last change, quantisation)."""
    from drivers.virtual.noise import NoiseModel

    noise, rng = NoiseModel(), np.random.default_rng(seed)
    v, i = truth.voltage, truth.current
    dv = np.diff(v, prepend=v[0])
    volts = np.array([noise.voltage(v[k], i[k], dv[k], rng, abs(dv[k])) for k in range(v.size)])
    amps = np.array([noise.current(x, rng) for x in i])
    temps = np.array([noise.temperature(x, rng) for x in truth.temperature])
    return {"voltage": volts, "current": amps, "temperature": temps}


def write_case(truth: Truth, path: str | Path, name: str, seed: int = 7) -> Path:
    """The noisy log of ``truth`` as BDF CSV at ``path`` (start SOC and ambient logged)."""
    from battlab.io.bdf import write_bdf_csv
    from battlab.io.data import AMBIENT, CURRENT, SURFACE, TIME, VOLTAGE, LoggedData

    m = logged(truth, seed)
    cols = {
        TIME: truth.t,
        VOLTAGE: m["voltage"],
        CURRENT: m["current"],
        AMBIENT: np.full(truth.t.size, AMBIENT_K - 273.15),
        SURFACE: m["temperature"] - 273.15,
    }
    return write_bdf_csv(LoggedData(name, cols, {"soc0": SOC0, "source": "PyBaMM"}), path)


def diagnose_cli(csv: Path, cell: str | Path, outdir: Path, timeout: float = 900.0) -> tuple[dict[str, Any], float]:
    """``battlab diagnose CSV --cell CELL -o OUTDIR`` in a subprocess (this checkout first on the path):
    summary.json and the wall time [s]."""
    import subprocess

    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    cmd = [
        sys.executable,
        "-c",
        "from battlab.cli import main; main()",
        "diagnose",
        str(csv),
        "--cell",
        str(cell),
        "-o",
        str(outdir),
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=timeout, check=False)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"battlab diagnose failed ({proc.returncode}): {proc.stderr[-2000:]}")
    return json.loads((Path(outdir) / "summary.json").read_text()), wall


def judge(case: Case, summary: dict[str, Any]) -> str:
    """``right`` (the hidden cause named; nothing named on the null), ``honest`` (nothing named, and the hidden cause
    listed as one the data cannot tell, or passing its score test, or not testable at all), ``missed`` (nothing
    named and the hidden cause in none of those) or ``WRONG`` (another cause named; any cause on the null)."""
    named = summary["cause"]
    if case.cause is None:
        return "right" if named is None else "WRONG"
    if named == case.cause:
        return "right"
    if named is not None:
        return "WRONG"
    listed = {r["cause"] for r in summary["ranking"] if r["passes"]}
    listed |= {k for c in summary.get("cannot_tell", []) for k in c.get("causes", [c["cause"]])}
    listed |= {c["cause"] if isinstance(c, dict) else c for c in summary.get("untestable", [])}
    tested = {r["cause"] for r in summary["ranking"]}
    return "honest" if case.cause in listed or case.cause not in tested else "missed"


def main() -> None:
    import argparse

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default=",".join(CASES), help="comma-separated: " + ", ".join(CASES))
    ap.add_argument("--out", default=None, help="keep the logs and reports here (default: a temporary folder)")
    ap.add_argument("--reuse", action="store_true", help="diagnose the logs already in --out (PyBaMM not rerun)")
    ap.add_argument("--no-diagnose", action="store_true", help="only make the logs")
    args = ap.parse_args()
    from battlab import Cell

    out = Path(args.out or tempfile.mkdtemp(prefix="pybamm_effects_"))
    out.mkdir(parents=True, exist_ok=True)
    cell = cell_file(out)
    prof = profile(float(Cell.from_bpx(cell)["Q_nom"]))
    rows = []
    for name in args.cases.split(","):
        case = CASES[name]
        csv = out / f"{name}.bdf.csv"
        if args.reuse and csv.is_file():
            print(f"{name}: reusing {csv}", flush=True)
        else:
            truth = solve(case, prof)
            write_case(truth, csv, name)
            print(
                f"{name}: PyBaMM {truth.seconds:.0f} s, charge error {truth.charge_error_Ah:.1e} Ah, "
                f"lithium lost {1e3 * truth.lithium_lost_Ah:.2f} mAh",
                flush=True,
            )
        if args.no_diagnose:
            continue
        s, wall = diagnose_cli(csv, cell, out / f"{name}_report")
        rank = ", ".join(f"{r['cause']} {r['score']:.3g}{'*' if r['passes'] else ''}" for r in s["ranking"][:3])
        g = s["extension_gain"]
        gain = f"{g['rmse_before_mV']:.2f}" + (f" -> {g['rmse_after_mV']:.2f}" if g["rmse_after_mV"] else "")
        rows.append((name, judge(case, s), s["cause"], rank, gain, wall))
        print(
            f"{name:<19} {rows[-1][1]:<7} named {s['cause']!s:<18} top3 [{rank}] held-out {gain} mV "
            f"(s² {s['residual']['s2']:.3g}, diagnose {wall:.0f} s)",
            flush=True,
        )
        print(f"    {case.size}; verdict: {s['verdict']}", flush=True)
    print(f"logs and reports in {out}")
    if any(r[1] == "WRONG" for r in rows):
        sys.exit(1)


if __name__ == "__main__":
    main()
