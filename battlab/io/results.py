"""Write simulation results with Battery Data Format column names (positive current = charge)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from battlab.io import paths
from battlab.simulation import Result
from protocols.errors import InputError

TIME = "Test Time / s"
VOLTAGE = "Voltage / V"
CURRENT = "Current / A"
AMBIENT = "Ambient Temperature / degC"
SURFACE = "Surface Temperature T1 / degC"
CORE = "Core Temperature / degC"  # model output; not a BDF column


def result_columns(res: Result, ambient_K: float) -> dict[str, np.ndarray]:
    """The result as named columns (temperatures in °C, as BDF logs them)."""
    cols = {
        TIME: res.t,
        VOLTAGE: res.voltage,
        CURRENT: res.current,
        AMBIENT: np.full(res.t.size, ambient_K - 273.15),
        SURFACE: res.T_surface - 273.15,
        CORE: res.T_core - 273.15,
    }
    if res.sensitivities is not None:
        for j, name in enumerate(res.parameters):
            cols[f"dV/d{name} / V"] = res.sensitivities[:, j]
            cols[f"dT_surface/d{name} / K"] = res.sensitivities_T[:, j]
    return cols


SUFFIXES = (".bdf.csv", ".csv", ".h5", ".hdf5")


def check_output_path(path: str | Path) -> Path:
    """An output path :func:`write_result` can write, checked before the work: suffix and directory."""
    return paths.check_output_path(path, SUFFIXES)


def write_result(res: Result, path: str | Path, ambient_K: float, meta: dict[str, Any]) -> Path:
    """Write ``.bdf.csv``/``.csv`` (with a JSON metadata sidecar ``<name>.summary.json``) or ``.h5``/``.hdf5``."""
    path = Path(path)
    cols = result_columns(res, ambient_K)
    meta = {**meta, "ended_by": res.ended_by, "sensitivity_parameters": list(res.parameters)}
    if path.suffix in (".h5", ".hdf5"):
        import h5py

        with h5py.File(path, "w") as f:
            g = f.create_group("data")
            for name, values in cols.items():
                g.create_dataset(name.replace("/", "per"), data=np.asarray(values), compression="gzip")
                g[name.replace("/", "per")].attrs["column"] = name
            for k, v in meta.items():
                f.attrs[k] = json.dumps(v)
        return path
    if path.suffix == ".csv":
        header = ",".join(cols)
        data = np.column_stack(list(cols.values()))
        np.savetxt(path, data, delimiter=",", header=header, comments="", fmt="%.10g")
        paths.summary_path(path).write_text(json.dumps(meta, indent=2))
        return path
    raise InputError(f"{path}: output must end in .bdf.csv, .csv, .h5 or .hdf5")
