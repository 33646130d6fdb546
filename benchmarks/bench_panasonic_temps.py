"""Benchmark: a fitted Panasonic NCR18650PF cell predicting the shared tests at 25, 10 and 0 °C from full charge.

    python benchmarks/bench_panasonic_temps.py CELL.bpx.json [--data DIR] [--dt 1] [--tests HWFET,US06,HPPC]
                                              [--temps 25,10,0] [--json OUT.json]

Each test is predicted the way a user (or an outside check) predicts logged data with the cell alone:
``battlab.simulate(cell, profile, soc0=1.0, ambient=T_K, T0=T_start, v_limits=(2.0, 4.5))``, with ``T_K`` the
chamber temperature (the file's mean ``Chamber_Temp_degC``, else the temperature in its name: the 10 and 0 °C
files log none) and ``T_start`` the logged surface temperature at the first sample (the 10 °C HWFET starts at
23.7 °C and rests an hour while it cools; every test starts from the 1C charge to 4.2 V with a 50 mA cut-off,
which is SOC 1 of a cell fitted by ``examples/panasonic/fit.sh``). Printed per file: voltage RMSE [mV] over the
whole test and up to 90 % of its discharged charge, the surface-temperature RMSE [K] against the logged
``Battery_Temp_degC``, the fraction of the test the prediction reached (it may stop at 2.0 V before the data do) and
the simulation's wall time. RMSEs cover the reached part.

The profile is the logged current resampled to ``--dt`` [s] (charge-conserving bin averages; 0 = the logged
samples). HPPC logs only the pulses and their rests; each logging gap (over 60 s) is filled with the constant
current that passes the charge its ``Ah`` column shows across the gap (the discharges between the pulses), so
that the prediction from full charge reaches every pulse at the logged charge; samples inside the gaps are not
scored.
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np

import battlab
from battlab.identify.experiments import read_delay, resample
from battlab.io.data import NET_CAPACITY, SURFACE, load_data
from protocols.profile import Profile

#: the shared data next to the repository (or next to the directory of its worktrees)
DATA = next(
    (p / "shared" / "data" / "panasonic-18650pf" for p in Path(__file__).resolve().parents if (p / "shared").is_dir()),
    Path("panasonic-18650pf"),
)
#: a time step longer than this [s] is a logging gap (HPPC's unlogged discharges)
GAP_S = 60.0


def conditions(path: Path) -> tuple[float, float]:
    """(ambient, start temperature) [K] of a logged test: the chamber's mean temperature (else the one in the
    file's name) and the surface temperature at its first sample (else the ambient)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = load_data(path)
    ambient = d.ambient_K(default=273.15 + float(path.name.split("degC")[0]))
    surf = d.temperature_K(SURFACE)
    return ambient, float(surf[0]) if surf is not None and np.isfinite(surf[0]) else ambient


def profile_of(path: Path, dt: float) -> tuple[Profile, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The logged test as a profile from its first sample, with the logged voltage [V], surface temperature [K],
    a mask of the samples to score (not inside a filled gap) and the discharged charge [Ah] at each sample. The
    voltage is read ``read_delay`` after each grid time: the drive tests log at 10 Hz and step their current between
    two readings, so the reading at a grid time is the left limit of the step there."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        d = load_data(path)
    t, i, v = d.t.copy(), d.current.copy(), d.voltage
    temp = d.temperature_K(SURFACE)
    gaps = np.flatnonzero(np.diff(t) > GAP_S)
    if gaps.size and NET_CAPACITY in d.columns:
        ah = np.asarray(d.columns[NET_CAPACITY], float)
        for k in gaps:
            i[k] = (ah[k + 1] - ah[k]) * 3600.0 / (t[k + 1] - t[k])
    lag = read_delay(t, dt)
    tt, ii, vv = resample(t, i, v, dt, lag)
    grid = tt + t[0]
    temp_g = np.interp(grid, t, temp) if temp is not None else np.full(grid.size, np.nan)
    scored = np.ones(grid.size, bool)
    for k in gaps:
        scored &= ~((grid > t[k]) & (grid < t[k + 1]))
    q = -np.concatenate([[0.0], np.cumsum(ii[:-1] * np.diff(tt))]) / 3600.0
    return Profile(tt, ii, id=path.stem), vv, temp_g, scored, q


def rmse(a: np.ndarray) -> float:
    a = a[np.isfinite(a)]
    return float(np.sqrt(np.mean(a**2))) if a.size else float("nan")


def score(cell: battlab.Cell, path: Path, dt: float) -> dict[str, float | str | None]:
    """Predict one test from full charge at its chamber and start temperatures; score voltage and temperature."""
    ambient, start = conditions(path)
    prof, v, temp, scored, q = profile_of(path, dt)
    t0 = time.perf_counter()
    res = battlab.simulate(cell, prof, soc0=1.0, ambient=ambient, T0=start, v_limits=(2.0, 4.5))
    sec = time.perf_counter() - t0
    n = res.voltage.size
    ev = 1e3 * (res.voltage - v[:n])
    et = res.T_surface - temp[:n]
    m = scored[:n]
    m90 = m & (q[:n] <= 0.9 * q.max())
    return {
        "rmse_mV": rmse(ev[m]),
        "rmse90_mV": rmse(ev[m90]),
        "rmse_T_K": rmse(et[m]),
        "coverage": n / v.size,
        "ended_by": res.ended_by,
        "seconds": sec,
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cell", help="the fitted cell (BPX)")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--dt", type=float, default=1.0, help="resample the logged current to this step [s]; 0 = raw")
    ap.add_argument("--tests", default="HWFET,US06,HPPC")
    ap.add_argument("--temps", default="25,10,0")
    ap.add_argument("--json", type=Path, default=None, help="write the scores here")
    a = ap.parse_args()
    cell = battlab.Cell.load(a.cell)
    out: dict[str, dict] = {}
    print(f"{'file':18s} {'V whole':>8s} {'V to 90%':>8s} {'T [K]':>6s} {'reached':>8s} {'sim s':>6s}  ended by")
    for temp in a.temps.split(","):
        for test in a.tests.split(","):
            path = a.data / f"{temp.strip()}degC_{test.strip()}.mat"
            if not path.exists():
                continue
            s = score(cell, path, a.dt)
            out[path.stem] = s
            print(
                f"{path.stem:18s} {s['rmse_mV']:8.1f} {s['rmse90_mV']:8.1f} {s['rmse_T_K']:6.2f} "
                f"{100 * s['coverage']:7.1f}% {s['seconds']:6.1f}  {s['ended_by'] or '-'}"
            )
    if a.json is not None:
        a.json.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
