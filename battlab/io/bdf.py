"""Battery Data Format CSV (``.bdf.csv``): import and export, with metadata in a ``<name>.summary.json`` sidecar.

A BDF CSV is one header row of BDF column names (``Test Time / s``, ``Voltage / V``, ``Current / A`` required)
and numbers; the reference package ``batterydf`` (``bdf.validate``) accepts what :func:`write_bdf_csv` writes.
Metadata (cell, protocol, start SOC, …) cannot live in a strict BDF CSV, so it goes to the sidecar, as
:mod:`battlab.io.results` does for simulation output.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from battlab.io.logged import REQUIRED, LoggedData
from battlab.io.paths import output_stem, summary_path
from protocols.errors import InputError

#: the sidecar's name before summaries had one name (still read)
LEGACY_SIDECAR_SUFFIX = ".meta.json"


def sidecar(path: str | Path) -> Path:
    """The metadata sidecar of a CSV: ``run.bdf.csv`` → ``run.summary.json``."""
    return summary_path(path)


def legacy_sidecar(path: str | Path) -> Path:
    """The sidecar's older name, still read: ``run.bdf.csv`` → ``run.meta.json``."""
    path = Path(path)
    return path.with_name(output_stem(path) + LEGACY_SIDECAR_SUFFIX)


def write_bdf_csv(data: LoggedData, path: str | Path) -> Path:
    """Write ``data`` as BDF CSV (required columns first) plus its metadata sidecar."""
    path = Path(path)
    if not path.name.endswith(".csv"):
        raise InputError(f"{path}: a BDF CSV file name ends in .bdf.csv (or .csv)")
    names = [*REQUIRED, *(c for c in data.columns if c not in REQUIRED)]
    for n in names:
        if "," in n or '"' in n:
            raise InputError(f"{path}: column name {n!r} contains a comma or quote")
    block = np.column_stack([data.columns[n] for n in names])
    np.savetxt(path, block, delimiter=",", header=",".join(names), comments="", fmt="%.10g")
    sidecar(path).write_text(json.dumps(dict(data.meta), indent=2, sort_keys=True, default=str))
    return path


def read_bdf_csv(path: str | Path) -> LoggedData:
    """Read a BDF CSV (and its sidecar if present); a missing column or a non-number names the line."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    try:
        with path.open(encoding="utf-8") as fh:
            header = [h.strip() for h in fh.readline().strip().split(",")]
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text CSV (binary content); expected a BDF CSV") from None
    if not header or header == [""]:
        raise InputError(f"{path}: file is empty")
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        sep = next((s for s in (";", "\t", "|") if len(header) == 1 and s in header[0]), None)
        hint = f" (separated by {sep!r}: a BDF CSV is comma-separated)" if sep else ""
        raise InputError(f"{path}: missing BDF column(s) {missing}; the header has {header}{hint}")
    import pandas as pd

    try:
        df = pd.read_csv(path, sep=",", skip_blank_lines=True)
    except (ValueError, pd.errors.ParserError) as exc:
        # pandas' message ends in a newline: keep the error on one line
        raise InputError(f"{path}: not a valid CSV table ({' '.join(str(exc).split())})") from None
    cols: dict[str, np.ndarray] = {}
    for name in df.columns:
        values = pd.to_numeric(df[name], errors="coerce").to_numpy(dtype=float)
        bad = np.zeros(values.size, bool)
        if not pd.api.types.is_numeric_dtype(df[name]):  # text in the column: which cells are not numbers?
            text = df[name].astype(str).str.strip().str.lower()
            bad = np.isnan(values) & ~text.isin(["nan", "", "none"]).to_numpy()
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            raise InputError(f"{path}, line {k + 2}: column {name!r}: expected a number, got {df[name].iloc[k]!r}")
        cols[str(name).strip()] = values
    meta = {}
    side = next((p for p in (sidecar(path), legacy_sidecar(path)) if p.is_file()), None)
    if side is not None:
        try:
            meta = json.loads(side.read_text(encoding="utf-8"))
        except ValueError as exc:  # invalid JSON or not UTF-8 text
            raise InputError(f"{side}: not valid JSON ({exc})") from None
    name = path.name.removesuffix(".csv").removesuffix(".bdf")
    return LoggedData(name, cols, meta, str(path))
