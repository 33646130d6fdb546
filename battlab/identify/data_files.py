"""Logged data for the fits: reading the files, telling the OCV test from dynamic data, the ambient of each file.

Shared by ``fit``, ``validate`` (:mod:`battlab.identify.workflow`), the value fits (:mod:`battlab.identify.values`)
and ``diagnose``.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from protocols.errors import InputError


def is_ocv_test(data: Any, q_nom: float) -> bool:
    """A slow test: |I| ≤ C/10 (5 % margin) for at least 5 h."""
    dur = float(data.t[-1] - data.t[0])
    return float(np.max(np.abs(data.current))) <= 0.1 * q_nom * 1.05 and dur >= 5 * 3600


def load_all(paths: Sequence[str | Path], *, fix_sign: bool = False) -> tuple[list[Any], list[str]]:
    """Logged data from files, and the warnings their readers raised (as text)."""
    from battlab.io.data import load_data

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        loaded = [load_data(p, fix_sign=fix_sign) for p in paths]
    return loaded, [str(w.message) for w in caught]


#: ambient temperatures [K] for logged data that do not log it: one value for all files, or per file (keys: the
#: path as given, its file name, or the data's name; "*" for all others)
Ambient = Mapping[str, float] | float | None


def ambient_of(data: Any, ambient: Ambient) -> float | None:
    """The ambient [K] given for ``data`` (None: use what the data logged)."""
    if ambient is None or isinstance(ambient, int | float):
        return None if ambient is None else float(ambient)
    source = str(data.source or "")
    for key in (source, Path(source).name, data.name, "*"):
        if key and key in ambient:
            return float(ambient[key])
    return None


def check_ambient_keys(paths: Sequence[str | Path], ambient: Ambient) -> None:
    """Every per-file ambient must name one of the data files (a typo must not silently fall back)."""
    if not isinstance(ambient, Mapping):
        return
    names = {str(p) for p in paths} | {Path(p).name for p in paths} | {Path(p).stem for p in paths} | {"*"}
    unknown = [k for k in ambient if k not in names]
    if unknown:
        raise InputError(f"--ambient {unknown[0]}=…: no data file of that name (files: {', '.join(map(str, paths))})")
