"""Import of the Panasonic NCR18650PF measurements (Kollmeyer, UW–Madison; MATLAB v5 ``.mat``, struct ``meas``).

Fields → BDF columns: ``Time`` → ``Test Time / s``, ``Voltage`` → ``Voltage / V``, ``Current`` (negative =
discharge, as BDF) → ``Current / A``, ``Ah`` → ``Net Capacity / Ah``, ``Battery_Temp_degC`` → ``Surface
Temperature T1 / degC``, ``Chamber_Temp_degC`` → ``Ambient Temperature / degC``, ``Power`` → ``Power / W``.

Pauses: in some files of this data set ``Time`` runs on across a pause of the test that the wall-clock
``TimeStamp`` shows (hours of rest that ``Time`` does not count). Where ``TimeStamp`` advances more than
:data:`PAUSE_MIN_S` beyond ``Time`` and more than twice ``Time``'s step, the pause is put back: a rest sample
(zero current) is inserted and the later samples are shifted so that time follows the wall clock, with a
:class:`~battlab.io.checks.DataWarning` naming the file, the place and the length.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path

import numpy as np

from battlab.io.checks import DataWarning
from battlab.io.logged import AMBIENT, CURRENT, NET_CAPACITY, SURFACE, TIME, VOLTAGE, LoggedData
from protocols.errors import InputError

FIELDS = {
    "Time": TIME,
    "Voltage": VOLTAGE,
    "Current": CURRENT,
    "Ah": NET_CAPACITY,
    "Battery_Temp_degC": SURFACE,
    "Chamber_Temp_degC": AMBIENT,
    "Power": "Power / W",
}
RATED_AH = 2.9
POWER = "Power / W"
#: a wall-clock advance this much [s] beyond ``Time``'s (and over twice ``Time``'s step) is a pause
PAUSE_MIN_S = 60.0
#: ``TimeStamp`` text as MATLAB's datestr writes it; at midnight the time of day is left out
STAMP_FORMATS = ("%m/%d/%Y %I:%M:%S %p", "%m/%d/%Y")
#: [K] a chamber column whose median is farther than this from the file name's temperature is wrong
CHAMBER_TOLERANCE_K = 3.0
#: [A] a slow test's charge-balance offset below this (about the Ah column's resolution over a day) is not said
OFFSET_MIN_A = 2e-3
#: [A] a test whose largest current is at most this (C/10 of the rated 2.9 Ah) is a slow (pseudo-OCV) test
SLOW_MAX_A = 0.1 * RATED_AH


def read_panasonic(path: str | Path) -> LoggedData:
    """Read one Panasonic 18650PF ``.mat`` file as :class:`LoggedData` (not yet checked; see ``load_data``)."""
    import scipy.io

    path = Path(path)
    try:
        raw = scipy.io.loadmat(path, squeeze_me=True, struct_as_record=False)
    except Exception as exc:  # noqa: BLE001 - scipy's parser fails on a broken file in many ways (IndexError, ...)
        raise InputError(f"{path}: not a readable MATLAB .mat file ({type(exc).__name__}: {exc})") from None
    if "meas" not in raw:
        raise InputError(f"{path}: no struct 'meas' (keys: {sorted(k for k in raw if not k.startswith('__'))})")
    meas = raw["meas"]
    names = getattr(meas, "_fieldnames", [])
    missing = [f for f in ("Time", "Voltage", "Current") if f not in names]
    if missing:
        raise InputError(f"{path}: struct 'meas' lacks field(s) {missing}; has {names}")
    try:
        cols = {col: np.asarray(getattr(meas, f), dtype=float).reshape(-1) for f, col in FIELDS.items() if f in names}
    except (TypeError, ValueError) as exc:
        raise InputError(f"{path}: struct 'meas' has a field that is not an array of numbers ({exc})") from None
    stamp = getattr(meas, "TimeStamp", None)
    stamps = np.atleast_1d(stamp).astype(str) if stamp is not None and np.size(stamp) else np.array([], str)
    start = str(stamps[0]) if stamps.size else ""
    meta = {
        "cell": "Panasonic NCR18650PF",
        "rated_capacity_Ah": RATED_AH,
        "source": "Kollmeyer, Panasonic 18650PF Li-ion Battery Data, Mendeley Data, doi:10.17632/wykht8y7tg.1",
        "start_time": start,
    }
    if TIME in cols and stamps.size == cols[TIME].size:
        cols, pauses = insert_pauses(cols, wall_clock_s(stamps), str(path), stamps)
        if pauses:
            meta["pauses"] = pauses
    cols = check_chamber(cols, meta, path)
    data = LoggedData(path.stem, cols, meta, str(path))
    found = charge_balance_offset(data)
    if found is not None:
        offset, text = found
        warnings.warn(f"{path}: {text}", DataWarning, stacklevel=2)
        data = LoggedData(path.stem, cols, {**meta, "current_offset_A": offset}, str(path))
    return data


def nominal_ambient_c(path: str | Path) -> float | None:
    """The test temperature [°C] in a Panasonic file's name (``10degC_US06.mat``, ``n10degC_…``), or None."""
    m = re.match(r"^(n|-)?(\d+(?:\.\d+)?)degC", Path(path).name)
    if m is None:
        return None
    return -float(m.group(2)) if m.group(1) else float(m.group(2))


def check_chamber(cols: dict[str, np.ndarray], meta: dict[str, object], path: Path) -> dict[str, np.ndarray]:
    """The nominal ambient from the file name into ``meta["ambient_K"]``; an empty or wrong chamber column said
    (a wrong one dropped, so the nominal is used)."""
    nominal = nominal_ambient_c(path)
    if nominal is None:
        return cols
    meta["ambient_K"] = nominal + 273.15
    chamber = cols.get(AMBIENT)
    if chamber is None:
        return cols
    finite = chamber[np.isfinite(chamber)]
    if finite.size == 0:
        warnings.warn(
            f"{path}: Chamber_Temp_degC is not logged (NaN); the ambient is the file name's {nominal:g} degC",
            DataWarning,
            stacklevel=3,
        )
        return {k: v for k, v in cols.items() if k != AMBIENT}
    median = float(np.median(finite))
    if abs(median - nominal) > CHAMBER_TOLERANCE_K:
        warnings.warn(
            f"{path}: Chamber_Temp_degC reads {median:g} degC (median), not the file name's {nominal:g} degC: the "
            "column is dropped and the ambient is the file name's",
            DataWarning,
            stacklevel=3,
        )
        return {k: v for k, v in cols.items() if k != AMBIENT}
    return cols


def charge_balance_offset(data: LoggedData) -> tuple[float, str] | None:
    """A slow test that discharges from its start and charges back to the voltage it started its discharge from
    (or above): the constant current offset [A] that makes both pass equal charge, with one line saying it; None
    when the test is not of that form or the offset is below :data:`OFFSET_MIN_A`.

    The offset is the net charge from the first to the last sample under current divided by the time under current
    (positive: the logged current reads low, too much discharge)."""
    t = np.asarray(data.columns[TIME], float)
    i = np.asarray(data.columns[CURRENT], float)
    v = np.asarray(data.columns[VOLTAGE], float)
    imax = float(np.max(np.abs(i))) if i.size else 0.0
    if not 0.0 < imax <= SLOW_MAX_A:
        return None
    on = np.abs(i) > 0.2 * imax
    dis, chg = np.flatnonzero(on & (i < 0)), np.flatnonzero(on & (i > 0))
    if dis.size < 10 or chg.size < 10 or chg[-1] < dis[-1] or v[chg[-1]] < v[dis[0]]:
        return None
    a, b = int(min(dis[0], chg[0])), int(max(dis[-1], chg[-1]))
    dt = np.diff(t[a : b + 1])
    net = float(np.sum(i[a:b] * dt))  # [C], positive = more charged than discharged
    under = float(np.sum(dt[on[a:b]]))
    offset = -net / under
    if abs(offset) < OFFSET_MIN_A:
        return None
    q_dis = -float(np.sum((i[a:b] * dt)[i[a:b] < 0])) / 3600.0
    q_chg = float(np.sum((i[a:b] * dt)[i[a:b] > 0])) / 3600.0
    text = (
        f"its charge back to {v[chg[-1]]:.3g} V returns {q_chg:.3f} Ah of the {q_dis:.3f} Ah its discharge counted: "
        f"a current offset of {-1e3 * offset:+.1f} mA in the logged current ({100 * abs(offset) / RATED_AH:.2f} % of "
        f"1C) over {under / 3600:.1f} h under current, if both end at one state; its discharged charge would then be "
        f"{abs(offset) * float(np.sum(dt[(i[a:b] < 0) & on[a:b]])) / 3600:.3f} Ah too {'high' if offset > 0 else 'low'}"
        " (not corrected here: battlab.io.panasonic.with_current_offset)"
    )
    return offset, text


def with_current_offset(data: LoggedData, offset: float) -> LoggedData:
    """``data`` with ``offset`` [A] added to the logged current where it flows (not at rest, where the cycler's
    output is off) and the ``Net Capacity`` column recounted from it."""
    i = np.asarray(data.columns[CURRENT], float)
    imax = float(np.max(np.abs(i)))
    on = np.abs(i) > 0.2 * imax
    new = np.where(on, i + offset, i)
    cols = dict(data.columns)
    cols[CURRENT] = new
    if NET_CAPACITY in cols:
        t = np.asarray(cols[TIME], float)
        start = float(cols[NET_CAPACITY][0])
        cols[NET_CAPACITY] = start + np.concatenate([[0.0], np.cumsum(new[:-1] * np.diff(t))]) / 3600.0
    meta = {**data.meta, "current_offset_corrected_A": offset}
    return LoggedData(data.name, cols, meta, data.source)


def wall_clock_s(stamps: np.ndarray) -> np.ndarray:
    """``TimeStamp`` text as seconds since the first stamp (NaN where a stamp cannot be read)."""
    import pandas as pd

    text = pd.Series(np.asarray(stamps, dtype=str)).str.strip()
    when = pd.to_datetime(text, format=STAMP_FORMATS[0], errors="coerce")
    for fmt in STAMP_FORMATS[1:]:
        when = when.fillna(pd.to_datetime(text, format=fmt, errors="coerce"))
    first = when.dropna()
    if first.empty:
        return np.full(len(text), np.nan)
    return (when - first.iloc[0]).dt.total_seconds().to_numpy(dtype=float)


def insert_pauses(
    cols: dict[str, np.ndarray], wall_s: np.ndarray, where: str, stamps: np.ndarray | None = None
) -> tuple[dict[str, np.ndarray], list[dict[str, float]]]:
    """Put back the pauses ``Time`` runs across: returns the columns and one record per pause.

    A pause lies between samples k and k+1 where the wall clock ``wall_s`` [s] advances by more than
    :data:`PAUSE_MIN_S` beyond ``Time`` and by more than twice ``Time``'s step. Sample k's current is taken to
    flow for ``Time``'s step, then the cell rests for the excess: a rest sample (zero current and power, the
    other columns as logged at k+1, the first sample after the rest) is inserted at the end of that step, and
    every later sample's time is shifted by the excess so that time follows the wall clock.
    """
    t = cols[TIME]
    dt, dw = np.diff(t), np.diff(wall_s)
    excess = dw - dt
    with np.errstate(invalid="ignore"):
        pause = (excess > PAUSE_MIN_S) & (dw > 2.0 * dt)
    ks = np.flatnonzero(pause)
    if ks.size == 0:
        return cols, []
    shift = np.zeros(t.size)
    for k in ks:
        shift[k + 1 :] += excess[k]
    out: dict[str, np.ndarray] = {}
    for name, values in cols.items():
        if name == TIME:
            rows = t[ks + 1] + shift[ks]  # the end of sample k's step, before this pause's shift
            base = t + shift
        elif name in (CURRENT, POWER):
            rows = np.zeros(ks.size)
            base = values
        else:
            rows = values[ks + 1]
            base = values
        out[name] = np.insert(base, ks + 1, rows)
    pauses = [{"after_sample": int(k), "t_s": float(t[k + 1] + shift[k]), "duration_s": float(excess[k])} for k in ks]
    total = float(excess[ks].sum())

    def place(k: int) -> str:
        wall = f", TimeStamp {stamps[k]} -> {stamps[k + 1]}" if stamps is not None else ""
        return f"after sample {k} (Time = {t[k]:.6g} s{wall}): {excess[k]:.0f} s ({excess[k] / 3600:.2f} h)"

    listed = "; ".join(place(int(k)) for k in ks[:3]) + (f"; and {ks.size - 3} more" if ks.size > 3 else "")
    warnings.warn(
        f"{where}: TimeStamp runs {total:.0f} s ({total / 3600:.2f} h) ahead of Time over {ks.size} pause(s) that "
        f"Time runs across: {listed}; inserted a rest (zero current) at each and shifted the later samples' time "
        "to follow the wall clock",
        DataWarning,
        stacklevel=3,
    )
    return out, pauses
