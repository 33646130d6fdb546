"""Half-cell OCP curves from CSV: read into a table, put into a cell, kept by BPX; bad files are one clear error."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from battlab import Cell
from battlab.io.ocp import read_ocp_csv, with_half_cell_ocp
from protocols.errors import InputError


def half_cell_csv(
    cell: Cell, electrode: str, path: Path, n: int = 400, header: str | None = "Stoichiometry,OCP / V"
) -> Path:
    """The cell's own OCP of ``electrode`` sampled at ``n`` stoichiometries over [0.01, 0.99], rows reversed."""
    x = np.linspace(0.01, 0.99, n)[::-1]
    u = cell.fn(f"U_{electrode}", x)
    rows = [f"{a:.10f},{b:.10f}" for a, b in zip(x, u, strict=True)]
    path.write_text("\n".join(([header] if header else []) + rows) + "\n")
    return path


def test_a_sampled_curve_reproduces_the_cells_own_ocv(nca18650: Cell, tmp_path: Path) -> None:
    """The positive OCP replaced by 400 samples of itself (linear interpolation): OCV within 0.2 mV over the
    window (tests/battlab/cli/test_cli_simulate.py simulates with an imported curve)."""
    csv = half_cell_csv(nca18650, "p", tmp_path / "nca_p.csv")
    table = read_ocp_csv(csv)
    assert table.x[0] == pytest.approx(0.01) and table.x[-1] == pytest.approx(0.99)  # sorted
    cell = with_half_cell_ocp(nca18650, "p", csv)
    soc = np.linspace(0.0, 1.0, 101)
    assert np.max(np.abs(cell.ocv(soc) - nca18650.ocv(soc))) < 2e-4
    assert cell.stoichiometry_window() == pytest.approx(nca18650.stoichiometry_window(), abs=1e-4)


def test_bpx_keeps_an_imported_curve(nca18650: Cell, tmp_path: Path) -> None:
    cell = with_half_cell_ocp(nca18650, "p", half_cell_csv(nca18650, "p", tmp_path / "p.csv", n=50, header=None))
    back = Cell.from_bpx(cell.to_bpx(tmp_path / "cell.bpx.json"))
    soc = np.linspace(0.0, 1.0, 21)
    np.testing.assert_allclose(back.ocv(soc), cell.ocv(soc), atol=1e-9)


def test_columns_are_found_by_name(nca18650: Cell, tmp_path: Path) -> None:
    path = tmp_path / "named.csv"
    x = np.linspace(0.1, 0.9, 9)
    path.write_text("U [V];theta\n" + "\n".join(f"{u};{t}" for t, u in zip(x, 4.2 - x, strict=True)))
    table = read_ocp_csv(path)
    np.testing.assert_allclose(table.x, x)
    np.testing.assert_allclose(table.y, 4.2 - x)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("sto,ocp\n0.1,4.1\n0.2,abc\n0.3,4.0\n0.4,3.9\n0.5,3.8\n", "line 3: not two numbers"),
        ("0.1,4.1\n0.2,4.0\n1.3,3.9\n0.4,3.8\n0.5,3.7\n", "line 3: stoichiometry 1.3 is outside [0, 1]"),
        ("0.1,4.1\n0.2,4.0\n0.3,41\n0.4,3.8\n0.5,3.7\n", "line 3: OCP 41 V is not a potential"),
        ("0.1,4.1\n0.2,4.0\n0.2,3.9\n0.4,3.8\n0.5,3.7\n", "lines 2 and 3: stoichiometry 0.2 appears twice"),
        ("0.1,4.1\n0.2,4.0\n", "2 points"),
        ("0.1\n0.2\n", "expected two columns"),
    ],
)
def test_a_bad_file_is_one_error_naming_file_and_line(text: str, message: str, tmp_path: Path) -> None:
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(InputError, match=re.escape(message)) as info:
        read_ocp_csv(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_a_curve_that_does_not_cover_the_window_is_refused(nca18650: Cell, tmp_path: Path) -> None:
    n0, n1, p0, p1 = nca18650.stoichiometry_window()
    path = tmp_path / "short.csv"
    x = np.linspace(min(p0, p1) + 0.05, 0.99, 20)
    path.write_text("\n".join(f"{a},{b}" for a, b in zip(x, nca18650.fn("U_p", x), strict=True)))
    # nca18650's window comes from its lithium and voltage limits: a curve short of it cannot reach them
    with pytest.raises(InputError, match="positive OCP, cell 'nca18650': the OCV does not reach") as info:
        with_half_cell_ocp(nca18650, "p", path)
    assert str(path) in str(info.value)
    fixed = nca18650.with_values(sto_n_0=n0, sto_n_100=n1, sto_p_0=p0, sto_p_100=p1)  # a cell that gives its window
    with pytest.raises(InputError, match=r"positive OCP covers stoichiometry .* but cell 'nca18650' uses"):
        with_half_cell_ocp(fixed, "p", path)
    with pytest.raises(InputError, match="electrode must be 'n'"):
        nca18650.with_ocp("q", read_ocp_csv(path))
