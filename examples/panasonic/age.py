"""Age the recipe's cell from the date of its OCV test to another date (battlab.identify.ageing).

    python examples/panasonic/age.py DATA_DIR WORK_DIR/c20.bdf.csv CELL.bpx.json DATE OUT.bpx.json

The fade rate comes from two dates at 25 degC: the rest voltages of the HPPC test (2017-03-11, after each hour's
rest, against the charge its Ah column counts from full) mapped onto the mean of the offset-corrected C/20 branches
(2017-05-08). Measured: the March cell had 1/0.9848 +- 0.0012 of the May cell's capacity (2.5 mV RMS, a constant
7.5 mV below the branches' mean: the hysteresis of a rest after discharge), 0.027 %/day. The cell is written as it
was on DATE: electrode area and lithium times the capacity factor, its OCV against SOC unchanged.
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np

import battlab
from battlab.identify import ageing as A
from battlab.io.data import NET_CAPACITY, load_data

#: first time stamps of the two tests the rate comes from (their files' TimeStamp[0])
HPPC_DATE, C20_DATE = "2017-03-11", "2017-05-08"


def branch_mean(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """The mean of an OCV test's discharge and charge branches against the discharged charge [Ah]."""
    d = load_data(path)
    i, t, v = d.current, d.t, d.voltage
    q = -np.concatenate([[0.0], np.cumsum(i[:-1] * np.diff(t))]) / 3600.0
    on = np.abs(i) > 0.2 * np.abs(i).max()
    dis, chg = on & (i < 0), on & (i > 0)
    lo, hi = max(q[dis].min(), q[chg].min()), min(q[dis].max(), q[chg].max())
    grid = np.linspace(lo, hi, 400)
    o = np.argsort(q[chg])
    return grid, 0.5 * (np.interp(grid, q[dis], v[dis]) + np.interp(grid, q[chg][o], v[chg][o]))


def main(argv: list[str]) -> int:
    if len(argv) != 5:
        print("usage: age.py DATA_DIR C20.bdf.csv CELL.bpx.json DATE OUT.bpx.json", file=sys.stderr)
        return 2
    data, c20, cell_path, date, out = Path(argv[0]), Path(argv[1]), argv[2], argv[3], argv[4]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        h = load_data(data / "25degC_HPPC.mat")
        qb, vb = branch_mean(c20)
    qa, va = A.rest_points(h.t, h.current, h.voltage, -np.asarray(h.columns[NET_CAPACITY]))
    keep = qa < 0.93 * qb.max()  # the last rests, near empty, are the least relaxed
    ratio = A.capacity_ratio(qa[keep], va[keep], qb, vb)
    fade = A.fade_from(HPPC_DATE, C20_DATE, ratio)
    cell = A.cell_on(battlab.Cell.load(cell_path), fade, date)
    cell.to_bpx(out)
    print(
        f"ageing: 25degC HPPC ({HPPC_DATE}) rests vs C/20 ({C20_DATE}): capacity ratio {ratio.ratio:.4f} +- "
        f"{ratio.ratio_se:.4f} ({ratio.points} rests, {ratio.rmse_mV:.1f} mV RMS, offset {1e3 * ratio.offset_V:.1f} "
        f"mV): {100 * fade.rate_per_day:.4f} %/day; cell on {date}: capacity x {fade.capacity(date):.4f} "
        f"({cell.capacity():.3f} Ah)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
