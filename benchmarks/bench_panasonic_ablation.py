"""Benchmark: which of a fitted Panasonic NCR18650PF cell's additions buys how much accuracy (leave-one-out).

    python benchmarks/bench_panasonic_ablation.py CELL.bpx.json [--data DIR] [--dt 1] [--tests HWFET,US06]
                                                  [--temps 25,10,0] [--json OUT.json]

A LEAVE-ONE-OUT WITHOUT REFIT: each row takes the cell of ``examples/panasonic/fit.sh`` and sets one group of what
the fit added beyond the base dynamics back to its off value, keeping every other value as fitted (nothing is
refitted around the change, so a row shows what that group contributes inside this fit, not what a fit without
it would reach):

- contact resistance: the contact-resistance extension off (its R_c on top of the fixed 15 mOhm; fit.sh step 3);
- solid diffusion: the stoichiometry-dependent D_s± off (D_s± at their half-lithiation values everywhere; step 3);
- ageing: the cell at the date of its OCV test instead of the 25 degC drive tests' (capacity / ``--aged-by``,
  step 2);
- activation energies: all fitted ones -> the built-in nominal cell's (step 4), and each one on its own;
- thermal: C1, C2 and h2a -> the nominal cell's (step 5).

What the C/20 test's current offset correction buys (fit.sh step 0) needs a refit of the equilibrium: measured with
the dynamics of the earlier recipe kept, the 25 degC HWFET to 90 % of its charge went 26.7 -> 15.8 mV.

Each test is scored as in ``bench_panasonic_temps.py`` (``simulate`` from full charge at the file's temperature):
voltage RMSE [mV] over the whole test, and the fraction of the test reached where below 100 %.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import battlab
from battlab.identify.ageing import aged_cell

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_panasonic_temps import DATA, score  # noqa: E402

#: the activation energies fit.sh's --arrhenius step fits
ACTIVATION = ("E_D_s_n", "E_D_s_p", "E_k_p", "E_kappa", "E_D_e")
THERMAL = ("C1", "C2", "h2a")


def variants(cell: battlab.Cell, nominal: battlab.Cell, aged_by: float = 1.0) -> list[tuple[str, battlab.Cell]]:
    """(label, cell) per row: the fitted cell, then each group set to its off value."""
    rows = [("fitted", cell)]
    if "contact_resistance" in cell.extensions:
        rows.append(("contact-resistance extension off", cell.without_extension("contact_resistance")))
    else:
        rows.append(("R_c -> 0", cell.with_values(R_c=0.0)))
    if "solid_diffusion" in cell.extensions:
        rows.append(("stoichiometry-dependent D_s off", cell.without_extension("solid_diffusion")))
    if aged_by != 1.0:
        why = "ablation: the cell at its OCV test's date"
        rows.append(
            (f"not aged (capacity / {aged_by:g})", aged_cell(cell, cell.lithium_moles() / aged_by, 1 / aged_by, why))
        )
    changed = [k for k in ACTIVATION if float(cell[k]) != float(nominal[k])]
    if changed:
        rows.append(("activation E -> nominal", cell.with_values(**{k: float(nominal[k]) for k in changed})))
        rows += [(f"{k} -> nominal", cell.with_values(**{k: float(nominal[k])})) for k in changed]
    rows.append(("thermal C1,C2,h2a -> nominal", cell.with_values(**{k: float(nominal[k]) for k in THERMAL})))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("cell", help="the fitted cell (BPX)")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--dt", type=float, default=1.0, help="resample the logged current to this step [s]; 0 = raw")
    ap.add_argument("--tests", default="HWFET,US06")
    ap.add_argument("--temps", default="25,10,0")
    ap.add_argument("--aged-by", type=float, default=1.0128, help="the capacity factor fit.sh's ageing step applied")
    ap.add_argument("--json", type=Path, default=None, help="write the scores here")
    a = ap.parse_args()
    cell = battlab.Cell.load(a.cell)
    nominal = battlab.Cell.load("nca18650")
    files = [a.data / f"{t.strip()}degC_{s.strip()}.mat" for s in a.tests.split(",") for t in a.temps.split(",")]
    files = [f for f in files if f.exists()]
    heads = [f.stem.replace("degC_", "C ") for f in files]
    print("voltage RMSE [mV] over the whole test (leave-one-out without refit; (r%) = part of the test reached)")
    print(f"{'row':30s}" + "".join(f"{h:>14s}" for h in heads) + f"{'mean':>8s}")
    out: dict[str, dict] = {}
    base_mean = None
    for label, c in variants(cell, nominal, a.aged_by):
        scores = {f.stem: score(c, f, a.dt) for f in files}
        out[label] = scores
        cells = []
        for f in files:
            s = scores[f.stem]
            reach = f"({100 * s['coverage']:.0f}%)" if s["coverage"] < 0.995 else ""
            cells.append(f"{s['rmse_mV']:8.1f}{reach:>6s}")
        mean = sum(s["rmse_mV"] for s in scores.values()) / len(scores)
        base_mean = mean if base_mean is None else base_mean
        delta = "" if label == "fitted" else f"  ({mean - base_mean:+.1f})"
        print(f"{label:30s}" + "".join(cells) + f"{mean:8.1f}{delta}", flush=True)
    if a.json is not None:
        a.json.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
