"""Prepare the Panasonic NCR18650PF recipe's inputs: the OCV test with its current offset corrected, and the start
cell.

    python examples/panasonic/prepare.py DATA_DIR WORK_DIR

Writes ``WORK_DIR/c20.bdf.csv``: the shared C/20 test with its logged current corrected for the offset its charge
balance shows (its charge back to 4.2 V returns 2.61 of the 2.99 Ah its discharge counted:
:func:`battlab.io.panasonic.charge_balance_offset`, about -9.9 mA). Uncorrected, its discharged charge is 0.2 Ah
high (a fitted capacity of 3.01 Ah against the 2.71 Ah the 25 degC HWFET delivers) and its branches are 70-150 mV
apart at equal counted charge; corrected, they are a near constant 37-47 mV apart (the C/20 overpotential and the
hysteresis, each branch about 20 mV from their mean) and their mean agrees with the 25 degC HPPC rest voltages to
6 mV RMS between 0.1 and 2.6 Ah.

Writes ``WORK_DIR/start.bpx.json``: the built-in ``nca18650`` with its fixed contact resistance R_c at
:data:`R_C_FIXED`, below the 25-31 mOhm the 25 degC HPPC shows 0.1 s into a pulse (cell and contacts), so that the
contact-resistance extension (a non-negative series resistance on top, exact sensitivities) fits the rest with the
dynamics in one stage.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import battlab
from battlab.io.bdf import write_bdf_csv
from battlab.io.data import load_data
from battlab.io.panasonic import charge_balance_offset, with_current_offset

#: [Ohm] the start cell's fixed contact resistance (the extension adds 0-20 mOhm)
R_C_FIXED = 0.015


def main(argv: list[str]) -> int:
    if len(argv) != 2:
        print("usage: prepare.py DATA_DIR WORK_DIR", file=sys.stderr)
        return 2
    src, work = Path(argv[0]) / "25degC_C20_OCV.mat", Path(argv[1])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        data = load_data(src)
    found = charge_balance_offset(data)
    if found is None:
        print(f"{src.name}: no charge-balance offset found; used as logged")
    else:
        offset, text = found
        print(f"{src.name}: {text}; corrected by {1e3 * offset:+.1f} mA")
        data = with_current_offset(data, offset)
    write_bdf_csv(data, work / "c20.bdf.csv")
    battlab.Cell.load("nca18650").with_values(R_c=R_C_FIXED).to_bpx(work / "start.bpx.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
