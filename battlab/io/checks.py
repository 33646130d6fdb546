"""Checks on logged data before it is fitted: NaN, unsorted time, duplicate stamps, gaps, the current's sign.

Errors (:class:`InputError`) and warnings (:class:`DataWarning`) name the file, the column and the sample range
(0-based sample indices and test times), so a bad row can be found in the file.
"""

from __future__ import annotations

import warnings

import numpy as np

from battlab.io.logged import CURRENT, REQUIRED, TIME, VOLTAGE, LoggedData
from protocols.errors import InputError


class DataWarning(UserWarning):
    """Something in logged data that the fit works around (gaps, duplicate stamps, NaN in optional columns)."""


def ranges(mask: np.ndarray, t: np.ndarray | None = None, limit: int = 3) -> str:
    """Contiguous runs of True in ``mask`` as text: 'samples 10–15 (t = 10–15 s), …'."""
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return "none"
    breaks = np.flatnonzero(np.diff(idx) > 1)
    starts = np.concatenate([[idx[0]], idx[breaks + 1]])
    ends = np.concatenate([idx[breaks], [idx[-1]]])
    parts = []
    for a, b in list(zip(starts, ends, strict=True))[:limit]:
        span = f"{a}" if a == b else f"{a}–{b}"
        when = ""
        if t is not None and np.isfinite(t[a]) and np.isfinite(t[b]):
            when = f" (t = {t[a]:.6g} s)" if a == b else f" (t = {t[a]:.6g}–{t[b]:.6g} s)"
        parts.append(f"sample{'s' if a != b else ''} {span}{when}")
    more = len(starts) - limit
    return ", ".join(parts) + (f" and {more} more run(s)" if more > 0 else "")


def detect_sign(t: np.ndarray, current: np.ndarray, voltage: np.ndarray) -> tuple[int, str]:
    """The current's sign convention from how the voltage moves: +1 (positive = charge), −1 (reversed), 0.

    Two statistics, each in [−1, 1]: the OCV direction (while a steady current flows the voltage moves with
    it: Σ I_k ΔV_k over steady samples) and the ohmic response (at current steps ΔV has the sign of ΔI for a
    positive resistance). The OCV direction decides when it is clear (|score| > 0.2), else the ohmic one.
    Returns (sign, explanation).
    """
    current = np.asarray(current, float)
    voltage = np.asarray(voltage, float)
    ok = np.isfinite(current) & np.isfinite(voltage)
    i, v = current[ok], voltage[ok]
    if i.size < 3 or not np.any(i != 0):
        return 0, "no current flows"
    di, dv, ik = np.diff(i), np.diff(v), i[:-1]
    thr = 0.01 * float(np.max(np.abs(i)))
    steady = (np.abs(di) <= thr) & (np.abs(ik) > thr)
    a, na = float(np.sum(ik[steady] * dv[steady])), float(np.sum(np.abs(ik[steady] * dv[steady])))
    steps = np.abs(di) > 5 * thr
    b, nb = float(np.sum(di[steps] * dv[steps])), float(np.sum(np.abs(di[steps] * dv[steps])))
    sa = a / na if na > 0 else 0.0
    sb = b / nb if nb > 0 else 0.0
    why = f"OCV-direction score {sa:+.2f} over {int(steady.sum())} steady samples, ohmic score {sb:+.2f}"
    if abs(sa) > 0.2:
        if abs(sb) > 0.5 and np.sign(sb) != np.sign(sa):
            return 0, why + " (they disagree)"
        return int(np.sign(sa)), why
    if abs(sb) > 0.2:
        return int(np.sign(sb)), why
    return 0, why


#: a step in time longer than this many times the data's median sampling interval (and than MIN_GAP_S) is a gap
GAP_FACTOR = 20.0
#: [s] the shortest step in time that counts as a gap, whatever the sampling
MIN_GAP_S = 60.0


def gap_threshold(t: np.ndarray, *, gap_factor: float = GAP_FACTOR, min_gap_s: float = MIN_GAP_S) -> float:
    """The longest step in time [s] that is not a gap: ``gap_factor`` × the median step of ``t`` [s], at least
    ``min_gap_s`` (a C/20 test logged every 60 s has no gaps at 60.01 s; a 1 s log has one at 61 s)."""
    dt = np.diff(np.asarray(t, dtype=float))
    dt = dt[dt > 0]
    typical = float(np.median(dt)) if dt.size else 0.0
    return max(gap_factor * typical, min_gap_s)


def _csv_line(data: LoggedData, bad: np.ndarray) -> str:
    """For data read from a CSV: where the first bad sample is in the file, and the header read (an empty or missing
    field reads as NaN: a short row, or a column the header does not have)."""
    if not str(data.source).lower().endswith(".csv"):
        return ""
    k = int(np.flatnonzero(bad)[0])
    return f"; line {k + 2} of the file, whose header has {list(data.columns)}"


def check_data(
    data: LoggedData, *, fix_sign: bool = False, gap_factor: float = GAP_FACTOR, min_gap_s: float = MIN_GAP_S
) -> LoggedData:
    """Check and clean ``data``; returns data with duplicate time stamps dropped (and the sign fixed if asked).

    Errors: NaN/inf in time, voltage or current; time that goes backwards; a current sign opposite to BDF's
    (positive = charge), unless ``fix_sign``. Warnings: NaN in other columns, repeated time stamps (the last
    sample of each repeat is kept: it carries the value after a change, as the zero-order hold wants), gaps
    longer than ``gap_factor`` × the median step and ``min_gap_s``.
    """
    where = data.source or data.name
    t = data.t
    if len(data) < 2:
        raise InputError(f"{where}: needs at least 2 samples, got {len(data)}")
    for col in REQUIRED:
        bad = ~np.isfinite(data.columns[col])
        if bad.any():
            raise InputError(f"{where}: column {col!r} is NaN or infinite at {ranges(bad, t)}{_csv_line(data, bad)}")
    for col, values in data.columns.items():
        if col not in REQUIRED and not np.isfinite(values).all():
            warnings.warn(
                f"{where}: column {col!r} is NaN at {ranges(~np.isfinite(values), t)}", DataWarning, stacklevel=2
            )
    dt = np.diff(t)
    back = dt < 0
    if back.any():
        k = int(np.flatnonzero(back)[0]) + 1
        raise InputError(
            f"{where}: time is not sorted: sample {k} (t = {t[k]:.6g} s) follows t = {t[k - 1]:.6g} s "
            f"({int(back.sum())} backward step(s) at {ranges(np.r_[False, back], t)})"
        )
    dup = np.r_[dt == 0, False]  # drop the earlier sample of each repeated stamp
    if dup.any():
        warnings.warn(
            f"{where}: {int(dup.sum())} repeated time stamp(s) at {ranges(dup, t)}; keeping the last sample of each",
            DataWarning,
            stacklevel=2,
        )
        data = data.select(~dup)
        t, dt = data.t, np.diff(data.t)
    if dt.size:
        longest = gap_threshold(t, gap_factor=gap_factor, min_gap_s=min_gap_s)
        gap = dt > longest
        if gap.any():
            warnings.warn(
                f"{where}: {int(gap.sum())} gap(s) in time longer than {longest:.3g} s "
                f"(largest {dt.max():.6g} s) after {ranges(np.r_[gap, False], t)}; the current is held over them",
                DataWarning,
                stacklevel=2,
            )
    sign, why = detect_sign(t, data.current, data.voltage)
    if sign < 0:
        charge = data.current > 0
        if not fix_sign:
            raise InputError(
                f"{where}: the current's sign looks reversed ({why}; positive current at {ranges(charge, t)}): "
                "BDF and battlab use positive = charge; flip the column (fix_sign=True, or --fix-sign)"
            )
        warnings.warn(
            f"{where}: current sign reversed ({why}); flipped to positive = charge", DataWarning, stacklevel=2
        )
        cols = dict(data.columns)
        cols[CURRENT] = -cols[CURRENT]
        data = LoggedData(data.name, cols, {**data.meta, "sign_flipped": True}, data.source)
    return data


__all__ = ["DataWarning", "check_data", "detect_sign", "gap_threshold", "ranges", "TIME", "VOLTAGE"]
