"""``battlab diagnose``: the contract's summary.json, the HTML report with its figures and the one-screen text;
bad input (data of another cell, an unknown cause, no ambient) is one line and exit code 2."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from battlab.cli import main
from battlab.io.bdf import write_bdf_csv
from battlab.io.data import AMBIENT, CURRENT, TIME, VOLTAGE, LoggedData

CATALOG = {
    "thermal",
    "hysteresis",
    "contact_resistance",
    "current_sensor",
    "capacity_fade",
    "equilibrium",
    "electrolyte",
    "solid_diffusion",
}


def test_diagnose_writes_the_summary_report_and_figures(tmp_path, hidden_effect_csv, monkeypatch) -> None:
    data = hidden_effect_csv(tmp_path / "null.bdf.csv")
    monkeypatch.chdir(tmp_path)
    out = Path("report")  # relative, as `-o report` is: the page still names its figures from its own folder
    r = CliRunner().invoke(main, ["diagnose", data, "--cell", "nca18650", "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert "cause: none" in r.output and "score tests" in r.output and "Traceback" not in r.output
    s = json.loads((out / "summary.json").read_text())
    assert s["cause"] is None
    assert {row["cause"] for row in s["ranking"]} == CATALOG
    assert all(isinstance(row["score"], float) for row in s["ranking"])
    assert set(s["extension_gain"]) >= {"rmse_before_mV", "rmse_after_mV", "held_out"}
    assert s["extension_gain"]["held_out"] == "null (final 30 %)"
    page = (out / "report.html").read_text()
    for png in ("residual.png", "conditional.png", "whiteness.png"):
        assert (out / png).is_file() and f'src="{png}"' in page


def _write(tmp_path, name: str, v: np.ndarray, i: np.ndarray, ambient: bool = True) -> str:
    t = np.arange(v.size, dtype=float)
    cols = {TIME: t, VOLTAGE: v, CURRENT: i}
    if ambient:
        cols[AMBIENT] = np.full(t.size, 25.0)
    return str(write_bdf_csv(LoggedData(name, cols, {"soc0": 0.9}), tmp_path / f"{name}.bdf.csv"))


@pytest.mark.parametrize(
    ("case", "expected"),
    [
        ("lfp", "leaves cell 'nca18650'"),
        ("capacity", "more than 1.5 × cell 'nca18650''s capacity 2.700 Ah: data and cell do not match"),
        ("cause", "cause 'double_layer' cannot be score-tested"),
        ("unknown", "unknown model extension 'ohm'"),
        ("ambient", "no ambient temperature logged"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(tmp_path, case: str, expected: str) -> None:
    n = 7200
    i = np.where(np.arange(n) > 10, -1.0, 0.0)
    v = np.linspace(3.9, 3.5, n)
    extra: list[str] = []
    if case == "lfp":
        path = _write(tmp_path, "lfp", v - 1.6, i)
    elif case == "capacity":
        path = _write(tmp_path, "big", v, 5 * i)
    elif case == "ambient":
        path = _write(tmp_path, "noamb", v, i, ambient=False)
    else:
        path = _write(tmp_path, "ok", v, i)
        extra = ["--cause", "double_layer" if case == "cause" else "ohm"]
    r = CliRunner().invoke(main, ["diagnose", path, "--cell", "nca18650", *extra, "-o", str(tmp_path / "o")])
    assert r.exit_code == 2, r.output
    assert "Traceback" not in r.output and expected in r.output, r.output
    assert len([ln for ln in r.output.splitlines() if ln.startswith("error:")]) == 1


@pytest.mark.slow
def test_several_files_hold_out_the_one_named_and_a_lone_held_out_file_is_refused(tmp_path, hidden_effect_csv) -> None:
    a = hidden_effect_csv(tmp_path / "a.bdf.csv", seed=2)
    b = hidden_effect_csv(tmp_path / "b.bdf.csv", seed=3)
    out = tmp_path / "r"
    r = CliRunner().invoke(main, ["diagnose", a, b, "--cell", "nca18650", "--held-out", a, "-o", str(out)])
    assert r.exit_code == 0, r.output
    s = json.loads((out / "summary.json").read_text())
    assert s["held_out"] == "a" and s["extension_gain"]["held_out"] == "a" and s["data"] == ["a", "b"]
    r = CliRunner().invoke(main, ["diagnose", a, "--cell", "nca18650", "--held-out", "a.bdf.csv", "-o", str(out)])
    assert r.exit_code == 2 and "no training data left" in r.output, r.output
