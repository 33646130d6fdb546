"""A :class:`~battlab.cell.Cell` → BPX JSON, the reader's conventions in reverse (see :mod:`battlab.io.bpx`)."""

from __future__ import annotations

import ast
import json
import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from battlab.cell import Cell, F
from battlab.functions import Expr, Function, Table, evaluate, to_json
from battlab.io.bpx.common import (
    CE_GRID,
    CONSTANTS,
    CP_NOMINAL,
    EXT,
    EXT_KEYS,
    EXT_MODEL,
    EXT_VERSION,
    EXT_WINDOW,
    PYBAMM_FUNCTIONS,
    STO_GRID,
)
from battlab.io.bpx.read import read_bpx, validate
from protocols.errors import InputError


# --- writing ---------------------------------------------------------------------------------------------
def write_bpx(cell: Cell, path: str | Path, **extra: Any) -> Path:
    """Write ``cell`` as BPX JSON (current schema of the installed ``bpx``), validated before writing.

    ``extra`` (e.g. ``confidence_intervals={"D_s_n": (lo, hi)}``, ``fit_report={...}``) is stored under
    "User-defined": numbers as they are, mappings and sequences flattened into "<name>: <key> [i]" entries,
    booleans as 0/1; texts are appended to the header's Description (PyBaMM takes User-defined entries as
    parameters and refuses texts there).
    """
    import bpx

    path = Path(path)
    v = cell.values
    n0, n1, p0, p1 = cell.stoichiometry_window()
    c_e0 = float(v["c_e0"])
    area = float(v["A"])
    stack = area * (float(v["L_n"]) + float(v["L_s"]) + float(v["L_p"]))
    c_tot = float(v["C1"]) + float(v["C2"])
    a_ext = 6.0 * stack ** (2.0 / 3.0)
    header: dict[str, Any] = {"BPX": bpx.__version__, "Title": cell.name, "Model": "DFN"}
    if cell.description:
        header["Description"] = cell.description
    refs = sorted({s for s in cell.sources.values() if s})
    if refs:
        header["References"] = "; ".join(refs)[:20000]

    def electrode(s: str) -> dict[str, Any]:
        eps_s, r_s, c_max = float(v[f"eps_s_{s}"]), float(v[f"R_s_{s}"]), float(v[f"c_max_{s}"])
        eps_e = float(v[f"eps_e_{s}"])
        d = _product(float(v[f"D_s_{s}"]), v.get(f"D_s_{s}_shape"))
        out: dict[str, Any] = {
            "Thickness [m]": float(v[f"L_{s}"]),
            "Porosity": eps_e,
            "Transport efficiency": float(v[f"B_{s}"]) if f"B_{s}" in v else eps_e ** float(v[f"brugg_{s}"]),
            "Conductivity [S.m-1]": float(v[f"sigma_{s}"]) * eps_s ** float(v[f"brugg_s_{s}"]),
            "Particle radius [m]": r_s,
            "Surface area per unit volume [m-1]": 3.0 * eps_s / r_s,
            "Maximum concentration [mol.m-3]": c_max,
            "Diffusivity [m2.s-1]": _bpx_function(d, STO_GRID),
            "Diffusivity activation energy [J.mol-1]": float(v[f"E_D_s_{s}"]),
            "OCP [V]": _bpx_function(v[f"U_{s}"], STO_GRID),
            "Entropic change coefficient [V.K-1]": _bpx_function(v[f"dUdT_{s}"], STO_GRID),
            "Reaction rate constant [mol.m-2.s-1]": float(v[f"k_{s}"]) * c_max * math.sqrt(c_e0) / F,
            "Reaction rate constant activation energy [J.mol-1]": float(v[f"E_k_{s}"]),
        }
        lo, hi = (n0, n1) if s == "n" else (p1, p0)
        out["Minimum stoichiometry"] = float(lo)
        out["Maximum stoichiometry"] = float(hi)
        return out

    eps_e_s = float(v["eps_e_s"])
    user: dict[str, Any] = {EXT_VERSION: 1, EXT_WINDOW: int("sto_n_0" not in v)}
    for key in EXT_KEYS:
        if key in v:
            val = v[key]
            user[EXT + key] = _bpx_text(val) if isinstance(val, Expr) else to_json(val)
    for key, vals in cell.extensions.items():
        for name, x in vals.items():
            user[f"{EXT_MODEL}{key}.{name}"] = float(x)
    descriptions: list[str] = []
    for name, value in extra.items():
        _flatten(name, value, user, descriptions)
    if descriptions:  # PyBaMM cannot take texts as parameters: they go to the header's description
        header["Description"] = "; ".join([*([cell.description] if cell.description else []), *descriptions])

    obj: dict[str, Any] = {
        "Header": header,
        "Parameterisation": {
            "Cell": {
                "Electrode area [m2]": area,
                "Number of electrode pairs connected in parallel to make a cell": 1,
                "Lower voltage cut-off [V]": float(v["V_min"]),
                "Upper voltage cut-off [V]": float(v["V_max"]),
                "Nominal cell capacity [A.h]": float(v["Q_nom"]),
                "Reference temperature [K]": float(v["T_ref"]),
                "Volume [m3]": stack,
                "External surface area [m2]": a_ext,
                "Density [kg.m-3]": c_tot / (CP_NOMINAL * stack),
                "Specific heat capacity [J.K-1.kg-1]": CP_NOMINAL,
            },
            "Electrolyte": {
                "Cation transference number": float(v["t_plus"]),
                "Diffusivity [m2.s-1]": _bpx_function(_product(float(v["D_e_scale"]), v["D_e"]), CE_GRID),
                "Diffusivity activation energy [J.mol-1]": float(v["E_D_e"]),
                "Conductivity [S.m-1]": _bpx_function(_product(float(v["kappa_scale"]), v["kappa"]), CE_GRID),
                "Conductivity activation energy [J.mol-1]": float(v["E_kappa"]),
            },
            "Negative electrode": electrode("n"),
            "Positive electrode": electrode("p"),
            "Separator": {
                "Thickness [m]": float(v["L_s"]),
                "Porosity": eps_e_s,
                "Transport efficiency": float(v["B_s"]) if "B_s" in v else eps_e_s ** float(v["brugg_s"]),
            },
            "User-defined": user,
        },
        "State": {
            "Initial conditions": {
                "Initial electrolyte concentration [mol.m-3]": c_e0,
                "Initial temperature [K]": float(v["T_ref"]),
            },
            "Thermal environment": {
                "Ambient temperature [K]": float(v["T_ref"]),
                "Heat transfer coefficient [W.m-2.K-1]": float(v["h2a"]) / a_ext,
            },
        },
    }
    validate(json.loads(json.dumps(obj)), f"BPX export of cell {cell.name!r}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj, indent=2) + "\n", encoding="utf-8")
    return path


def _product(scale: float, f: float | Function | None) -> float | Function:
    """scale × f (f a number, an expression, a table or None for 1)."""
    if f is None:
        return scale
    if isinstance(f, float | int):
        return scale * float(f)
    if scale == 1.0:
        return f
    if isinstance(f, Table):
        return Table(f.x, tuple(scale * y for y in f.y))
    return Expr(f"{scale!r}*({f.text})")


def _bpx_function(f: float | Function, grid: np.ndarray) -> Any:
    """A BPX value PyBaMM can use: a number, an expression in exp/tanh/cosh, else a table on ``grid``."""
    if isinstance(f, float | int):
        return float(f)
    if isinstance(f, Expr) and _call_names(f) <= PYBAMM_FUNCTIONS:
        return _bpx_text(f)
    if isinstance(f, Table):
        return to_json(f)
    y = np.asarray(evaluate(f, grid), float)
    return {"x": [float(t) for t in grid], "y": [float(t) for t in y]}


def _call_names(f: Expr) -> set[str]:
    tree = ast.parse(f.text, mode="eval")
    return {n.func.id for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}


class _Inline(ast.NodeTransformer):
    """Replace the named constants pi and e by numbers (BPX functions know only the variable x)."""

    def visit_Name(self, node: ast.Name) -> ast.AST:
        if node.id in CONSTANTS:
            return ast.copy_location(ast.Constant(CONSTANTS[node.id]), node)
        return node


def _bpx_text(f: Expr) -> str:
    """The expression in BPX syntax: its own text unless it names a constant."""
    tree = ast.parse(f.text, mode="eval")
    if not any(isinstance(n, ast.Name) and n.id in CONSTANTS for n in ast.walk(tree)):
        return f.text
    return ast.unparse(_Inline().visit(tree))


def _flatten(name: str, value: Any, out: dict[str, Any], texts: list[str]) -> None:
    """Store ``value`` under User-defined as numbers (BPX accepts numbers, functions and tables only)."""
    if value is None:
        return
    if isinstance(value, bool | np.bool_):
        out[name] = int(bool(value))
    elif isinstance(value, int | float | np.integer | np.floating):
        x = float(value)
        if not math.isfinite(x):
            texts.append(f"{name}: {x}")
        else:
            out[name] = x
    elif isinstance(value, str):
        texts.append(f"{name}: {value}")
    elif isinstance(value, Mapping):
        for k, sub in value.items():
            _flatten(f"{name}: {k}", sub, out, texts)
    elif isinstance(value, Iterable):
        for i, sub in enumerate(value):
            _flatten(f"{name} [{i}]", sub, out, texts)
    else:
        raise InputError(
            f"BPX export: extra metadata {name!r} must be numbers, texts, mappings or sequences, "
            f"got {type(value).__name__}"
        )


__all__ = ["read_bpx", "write_bpx", "EXT"]
