"""Open-circuit potential curves from CSV (half-cell measurements): stoichiometry and potential vs Li/Li⁺.

The file holds two columns (separated by commas, semicolons, tabs or spaces), with or without a header: the
stoichiometry θ ∈ [0, 1] (lithium fraction of the electrode) and the potential U [V]. With a header, columns are
found by name (``sto``/``stoichiometry``/``x``/``theta`` and ``ocp``/``u``/``potential``/``voltage``; units after a
space or slash are ignored), else the first two are taken. Rows may come in any order; they are sorted by θ. The
curve becomes a linearly interpolated table (:class:`battlab.functions.Table`, BPX's tabulated function) for
:meth:`battlab.cell.Cell.with_ocp`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from battlab.cell import Cell
from battlab.functions import Table
from protocols.errors import InputError

STO_NAMES = ("sto", "stoichiometry", "x", "theta", "lithiation")
OCP_NAMES = ("ocp", "u", "potential", "voltage", "e", "v")
#: fewest points that make a curve
MIN_POINTS = 5
#: potentials vs Li/Li⁺ [V] an electrode can have
U_RANGE = (-0.5, 6.0)


def _key(name: object) -> str:
    return str(name).strip().lower().replace("/", " ").split(" ")[0]


def read_ocp_csv(path: str | Path) -> Table:
    """The curve in ``path`` as a table; a file that is not one is an :class:`InputError` naming the file and
    the line."""
    import pandas as pd

    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: OCP file not found")
    try:
        first_line = next((ln for ln in p.read_text().splitlines() if ln.strip() and not ln.startswith("#")), "")
        sep = next((d for d in (",", ";", "\t") if d in first_line), r"\s+")
        df = pd.read_csv(p, sep=sep, engine="python", comment="#", header=None, dtype=str, skip_blank_lines=True)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: not a CSV of stoichiometry and OCP ({str(exc).splitlines()[0]})") from None
    if df.shape[1] < 2:
        raise InputError(f"{p}: expected two columns (stoichiometry, OCP [V]), found {df.shape[1]}")
    first = pd.to_numeric(df.iloc[0], errors="coerce")
    header = bool(first.isna().all())
    cols = (0, 1)
    if header:
        names = [_key(v) for v in df.iloc[0]]
        sto = next((k for k, n in enumerate(names) if n in STO_NAMES), None)
        ocp = next((k for k, n in enumerate(names) if n in OCP_NAMES), None)
        if sto is not None and ocp is not None and sto != ocp:
            cols = (sto, ocp)
        df = df.iloc[1:]
    lines = np.arange(df.shape[0]) + (2 if header else 1)  # 1-based line numbers (blank and comment lines aside)
    x = pd.to_numeric(df.iloc[:, cols[0]], errors="coerce").to_numpy(float)
    u = pd.to_numeric(df.iloc[:, cols[1]], errors="coerce").to_numpy(float)
    bad = ~(np.isfinite(x) & np.isfinite(u))
    if bad.any():
        raise InputError(f"{p}, line {lines[bad][0]}: not two numbers (stoichiometry, OCP [V])")
    if x.size < MIN_POINTS:
        raise InputError(f"{p}: {x.size} points; an OCP curve needs at least {MIN_POINTS}")
    out = (x < 0.0) | (x > 1.0)
    if out.any():
        raise InputError(f"{p}, line {lines[out][0]}: stoichiometry {x[out][0]:g} is outside [0, 1]")
    wild = (u < U_RANGE[0]) | (u > U_RANGE[1])
    if wild.any():
        raise InputError(
            f"{p}, line {lines[wild][0]}: OCP {u[wild][0]:g} V is not a potential vs Li/Li+ "
            f"({U_RANGE[0]:g}-{U_RANGE[1]:g} V)"
        )
    order = np.argsort(x, kind="stable")
    x, u, lines = x[order], u[order], lines[order]
    same = np.flatnonzero(np.diff(x) == 0.0)
    if same.size:
        k = same[0]
        raise InputError(f"{p}, lines {lines[k]} and {lines[k + 1]}: stoichiometry {x[k]:g} appears twice")
    return Table(tuple(x), tuple(u))


def with_half_cell_ocp(cell: Cell, electrode: str, path: str | Path) -> Cell:
    """``cell`` with electrode ``"n"`` or ``"p"``'s OCP read from ``path``."""
    return cell.with_ocp(electrode, read_ocp_csv(path), source=str(path))
