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
    return LoggedData(path.stem, cols, meta, str(path))


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
