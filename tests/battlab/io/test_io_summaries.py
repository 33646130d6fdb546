"""One name for every summary and metadata sidecar: ``<output stem>.summary.json``; older names still read."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from battlab.io.bdf import read_bdf_csv, write_bdf_csv
from battlab.io.logged import CURRENT, TIME, VOLTAGE, LoggedData
from battlab.io.paths import summary_path


@pytest.mark.parametrize(
    ("output", "summary"),
    [
        ("plan.toml", "plan.summary.json"),
        ("out/cell.bpx.json", "out/cell.summary.json"),
        ("run.bdf.csv", "run.summary.json"),
        ("sens.h5", "sens.summary.json"),
        ("fitted.json", "fitted.summary.json"),
        ("a.b.toml", "a.b.summary.json"),
    ],
)
def test_the_summary_is_named_after_the_output(output: str, summary: str) -> None:
    assert summary_path(output) == Path(summary)


def test_a_directory_output_holds_its_summary() -> None:
    assert summary_path("validation", directory=True) == Path("validation/validation.summary.json")
    assert summary_path("out/v/", directory=True) == Path("out/v/v.summary.json")


def _data() -> LoggedData:
    t = np.arange(5.0)
    return LoggedData("r", {TIME: t, VOLTAGE: np.full(5, 3.7), CURRENT: np.zeros(5)}, {"soc0": 0.5})


def test_a_bdf_csv_sidecar_is_the_summary_name_and_reads_back(tmp_path: Path) -> None:
    path = write_bdf_csv(_data(), tmp_path / "run.bdf.csv")
    assert (tmp_path / "run.summary.json").is_file() and not (tmp_path / "run.meta.json").exists()
    assert read_bdf_csv(path).meta == {"soc0": 0.5}


def test_an_older_meta_json_sidecar_is_still_read(tmp_path: Path) -> None:
    path = write_bdf_csv(_data(), tmp_path / "run.bdf.csv")
    (tmp_path / "run.summary.json").rename(tmp_path / "run.meta.json")
    assert read_bdf_csv(path).meta == {"soc0": 0.5}
    (tmp_path / "run.summary.json").write_text(json.dumps({"soc0": 0.25}))  # the current name wins
    assert read_bdf_csv(path).meta == {"soc0": 0.25}
