"""Benchmark: robustness of a fitted Panasonic NCR18650PF cell at low temperatures (stress set).

    python benchmarks/bench_panasonic_cold.py CELL.bpx.json [--data DIR] [--dt 1] [--only SUBSTR] [--json OUT]

Every case runs ``battlab.simulate(cell, profile, soc0=1.0, ambient=T_K, v_limits=(2.0, 4.5))`` from full charge,
as an outside check predicting other tests of this cell does:

- the logged current of the shared 10 and 0 °C US06 and HWFET tests (``--data``), simulated at ambients 0, -10
  and -20 °C (voltage RMSE [mV] printed where the ambient is the test's own);
- the package drive cycles (UDDS, US06, HWFET, WLTC 3b, the naturalistic DC1 and DC2) through the package's EV
  model, scaled so that the largest discharge current is 3.5C of the cell's nominal capacity (regeneration scaled
  with it where the cycle has it), repeated until well past a full discharge, at 25, 0, -10 and -20 °C; and at
  -10 and -20 °C also without regeneration (``/noregen``: the charging current clipped at 0 A, as the lab ran the
  shared 0 °C tests).

Printed per case: the fraction of the profile reached, the simulated duration [s], why it ended (the 2.0 V cut-off
is a clean stop; "solver: ..." is a failure) and the wall time. Exit status 1 when any case ended in a solver
failure.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import battlab
from protocols.drive_cycles import Cycle, speed_trace
from protocols.ev_model import EVModel
from protocols.profile import Profile

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_panasonic_temps import DATA, profile_of, rmse  # noqa: E402

#: the largest discharge current of a package drive cycle, in C of the cell's nominal capacity
PEAK_C = 3.5


def cycle_profile(
    cycle: Cycle, q_nom_ah: float, peak_c: float = PEAK_C, discharge_ah: float = 1.6, regen: bool = True
) -> Profile:
    """``cycle`` through the default EV model, scaled to a largest discharge of ``peak_c`` C (charging current
    clipped at 0 A unless ``regen``) and repeated until its net discharge passes ``discharge_ah`` times the nominal
    capacity [A h] (so the run ends at the cut-off)."""
    trace = speed_trace(cycle)
    i = EVModel().cell_current(trace.t, trace.speed_mps, trace.grade)  # positive = charge
    i = i * (peak_c * q_nom_ah / float(-np.min(i)))
    if not regen:
        i = np.minimum(i, 0.0)
    dt = np.diff(trace.t)
    net_ah = float(-np.sum(i * dt)) / 3600.0
    k = int(np.ceil(discharge_ah * q_nom_ah / max(net_ah, 1e-9)))
    t = np.concatenate([[0.0], np.cumsum(np.tile(dt, k))])
    ii = np.tile(i, k)
    return Profile(t, np.concatenate([ii, ii[-1:]]), id=cycle.value if regen else f"{cycle.value}/noregen")


def cases(data: Path, dt: float, q_nom: float, only: str) -> list[tuple[str, Profile, float, np.ndarray | None]]:
    """(name, profile, ambient [°C], logged voltage where the ambient is the test's own, else None)."""
    out = []
    for temp in (10, 0):
        for test in ("US06", "HWFET"):
            path = data / f"{temp}degC_{test}.mat"
            if not path.exists():
                continue
            prof, v, _, _, _ = profile_of(path, dt)
            for amb in (0, -10, -20):
                out.append((f"{path.stem}@{amb}", prof, float(amb), v if amb == temp else None))
    for cyc in Cycle:
        prof = cycle_profile(cyc, q_nom)
        for amb in (25, 0, -10, -20):
            out.append((f"{cyc.value}@{amb}", prof, float(amb), None))
        prof = cycle_profile(cyc, q_nom, regen=False)
        for amb in (-10, -20):
            out.append((f"{cyc.value}/noregen@{amb}", prof, float(amb), None))
    return [c for c in out if only in c[0]]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cell", help="the fitted cell (BPX)")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--dt", type=float, default=1.0, help="resample the logged current to this step [s]")
    ap.add_argument("--only", default="", help="only the cases whose name contains this")
    ap.add_argument("--json", type=Path, default=None, help="write the results here")
    a = ap.parse_args()
    cell = battlab.Cell.load(a.cell)
    q_nom = float(cell["Q_nom"])
    print(f"{'case':24s} {'reached':>8s} {'t end s':>8s} {'V mV':>6s} {'sim s':>6s}  ended by")
    out: dict[str, dict] = {}
    failed = 0
    for name, prof, amb, v in cases(a.data, a.dt, q_nom, a.only):
        t0 = time.perf_counter()
        res = battlab.simulate(cell, prof, soc0=1.0, ambient=273.15 + amb, v_limits=(2.0, 4.5))
        sec = time.perf_counter() - t0
        n = res.voltage.size
        err = rmse(1e3 * (res.voltage - v[:n])) if v is not None else float("nan")
        why = res.ended_by or "-"
        failed += why.startswith("solver")
        out[name] = {"reached": n / prof.t.size, "t_end_s": float(res.t[-1]) if n else 0.0, "rmse_mV": err}
        out[name] |= {"ended_by": why, "seconds": sec}
        print(f"{name:24s} {100 * n / prof.t.size:7.1f}% {out[name]['t_end_s']:8.0f} {err:6.1f} {sec:6.1f}  {why}")
    if a.json is not None:
        a.json.write_text(json.dumps(out, indent=2))
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
