"""Import of the Panasonic NCR18650PF measurements (Kollmeyer, UW–Madison; MATLAB v5 ``.mat``, struct ``meas``).

Fields → BDF columns: ``Time`` → ``Test Time / s``, ``Voltage`` → ``Voltage / V``, ``Current`` (negative =
discharge, as BDF) → ``Current / A``, ``Ah`` → ``Net Capacity / Ah``, ``Battery_Temp_degC`` → ``Surface
Temperature T1 / degC``, ``Chamber_Temp_degC`` → ``Ambient Temperature / degC``, ``Power`` → ``Power / W``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

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
    start = str(np.atleast_1d(stamp)[0]) if stamp is not None and np.size(stamp) else ""
    meta = {
        "cell": "Panasonic NCR18650PF",
        "rated_capacity_Ah": RATED_AH,
        "source": "Kollmeyer, Panasonic 18650PF Li-ion Battery Data, Mendeley Data, doi:10.17632/wykht8y7tg.1",
        "start_time": start,
    }
    return LoggedData(path.stem, cols, meta, str(path))
