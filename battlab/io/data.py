"""Logged data in memory: named BDF columns plus metadata, and one loader for every supported file kind.

Columns are named as in the Battery Data Format (``Test Time / s``, ``Voltage / V``, ``Current / A``, …);
current is positive on charge; temperatures are in °C as logged. :func:`load_data` reads our HDF5 run log
(``.h5``/``.hdf5``), a BDF CSV (``.csv``, with an optional ``<name>.summary.json`` sidecar) or a Panasonic
18650PF ``.mat`` file, and checks it (NaN, unsorted time, gaps, sign convention; see :mod:`battlab.io.checks`).
"""

from __future__ import annotations

from pathlib import Path

from battlab.io.bdf import read_bdf_csv
from battlab.io.checks import check_data
from battlab.io.logged import (
    AMBIENT,
    CURRENT,
    NET_CAPACITY,
    REQUIRED,
    STEP,
    SURFACE,
    TIME,
    VOLTAGE,
    LoggedData,
)
from battlab.io.logs import read_log
from battlab.io.panasonic import read_panasonic
from protocols.errors import InputError

__all__ = [
    "AMBIENT",
    "CURRENT",
    "NET_CAPACITY",
    "REQUIRED",
    "STEP",
    "SURFACE",
    "TIME",
    "VOLTAGE",
    "LoggedData",
    "load_data",
]


def load_data(path: str | Path, *, fix_sign: bool = False) -> LoggedData:
    """Read logged data: ``.h5``/``.hdf5`` (our run log), ``.csv`` (BDF CSV) or ``.mat`` (Panasonic 18650PF).

    The data are checked (:func:`battlab.io.checks.check_data`): NaN, unsorted time and a reversed current sign
    are errors naming the file and the sample range (``fix_sign=True`` flips a reversed sign with a warning);
    gaps and duplicate time stamps are warnings.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such data file")
    suffix = path.suffix.lower()
    if suffix in (".h5", ".hdf5"):
        data = read_log(path)
    elif suffix == ".csv":
        data = read_bdf_csv(path)
    elif suffix == ".mat":
        data = read_panasonic(path)
    else:
        raise InputError(f"{path}: unknown data format {suffix!r}; expected .h5/.hdf5 (run log), .csv (BDF) or .mat")
    return check_data(data, fix_sign=fix_sign)
