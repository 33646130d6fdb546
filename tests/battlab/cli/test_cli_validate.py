"""``battlab validate``: its page shows its figures wherever it is opened from, and it scores data sampled slower
than once a minute (the shared C/20 OCV test) as ``battlab fit`` reads them."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest
from click.testing import CliRunner

from battlab.cli import main
from battlab.report.browser import PageCheck


def test_the_page_in_a_relative_directory_shows_every_figure_from_elsewhere(
    tmp_path: Path,
    virtual_csv: Callable[[Path, int, int], str],
    monkeypatch: pytest.MonkeyPatch,
    open_elsewhere: Callable[[Path], PageCheck],
) -> None:
    data = virtual_csv(tmp_path, 37, 2)
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(main, ["validate", data, "--cell", "nca18650", "-o", "v"])
    assert r.exit_code == 0, r.output
    text = (tmp_path / "v" / "report.html").read_text()
    assert 'src="p37.png"' in text and 'src="error_cdf.png"' in text and 'src="v/' not in text
    check = open_elsewhere(tmp_path / "v" / "report.html")
    assert check.images == 2 and check.images_loaded == 2 and check.ok


@pytest.mark.parametrize("dt", ["60", "100"])
def test_the_shared_c20_ocv_test_sampled_every_60_s_is_scored(tmp_path: Path, shared_data: Path, dt: str) -> None:
    """One segment (its 60.01 s steps are its sampling, not gaps), resampled at --dt; the nominal cell's discharge
    ends before the data's (V < V_min - 0.15), so the RMSE covers part of it, as the output says."""
    ocv = shared_data / "panasonic-18650pf" / "25degC_C20_OCV.mat"
    r = CliRunner().invoke(main, ["validate", str(ocv), "--cell", "nca18650", "--dt", dt, "-o", str(tmp_path / "v")])
    assert r.exit_code == 0, r.output
    assert "no segment" not in r.output
    s = json.loads((tmp_path / "v" / "v.summary.json").read_text())
    assert list(s["rmse_mV"]["nca18650"]) == ["25degC_C20_OCV"]
    assert 0 < s["rmse_mV"]["nca18650"]["25degC_C20_OCV"] < 200  # measured: 102 mV (--dt 60), 104 mV (--dt 100)
    assert 0.3 < s["coverage"]["nca18650"]["25degC_C20_OCV"] < 1.0  # measured: 0.46
