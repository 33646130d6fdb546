"""The static HTML report: escaping, relative figure paths, and a real headless Chromium that renders the page
and loads every image (and notices a missing one)."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from battlab.report import Figure, KeyValues, Paragraph, Section, Table, render, write
from battlab.report.browser import PageCheck, check_page
from battlab.report.campaign import _health


def figure(path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4, 3))
    ax.plot(np.arange(10), np.arange(10) ** 2)
    fig.savefig(path)
    plt.close(fig)
    return path


def sections(fig: Path) -> list[Section]:
    return [
        Section("Headline", [Paragraph("RMSE <b>2.1 mV</b> & all good", tone="good"), KeyValues({"s²": 1.02})]),
        Section(
            "Recovery", [Table(["parameter", "truth", "estimate"], [["D_s_n", 2.634e-14, 2.7e-14], ["x", None, 1.0]])]
        ),
        Section("Figures", [Figure(fig, "error CDF")]),
    ]


def test_text_is_escaped_and_figures_are_relative(tmp_path: Path) -> None:
    (tmp_path / "figs").mkdir()
    fig = figure(tmp_path / "figs" / "a.png")
    page = write(tmp_path / "report.html", "Campaign <1>", sections(fig))
    text = page.read_text()
    assert "<b>2.1 mV</b>" not in text and "&lt;b&gt;2.1 mV&lt;/b&gt; &amp; all good" in text
    assert 'src="figs/a.png"' in text
    assert "<title>Campaign &lt;1&gt;</title>" in text
    assert "2.634e-14" in text and "–" in text
    assert "<script" not in render("t", sections(fig))


def test_chromium_renders_the_page_with_every_image(tmp_path: Path, chromium: str) -> None:
    fig = figure(tmp_path / "fig.png")
    page = write(tmp_path / "report.html", "Campaign", sections(fig))
    check = check_page(page, tmp_path / "shot.png")
    assert check.images == 1 and check.images_loaded == 1 and not check.blank and check.ok
    assert not (set(tmp_path.glob("tmp*.html")))  # the probe copy is removed


def test_a_missing_figure_is_noticed(tmp_path: Path, chromium: str) -> None:
    page = write(tmp_path / "report.html", "Campaign", sections(tmp_path / "missing.png"))
    check = check_page(page, tmp_path / "shot.png")
    assert check.images == 1 and check.images_loaded == 0 and not check.ok


def test_a_page_in_a_relative_directory_finds_its_figures_from_another_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, open_elsewhere: Callable[[Path], PageCheck]
) -> None:
    """Written as `-o out` writes it (figures given relative to the working directory), opened from elsewhere."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "out" / "figs").mkdir(parents=True)
    fig = figure(Path("out/figs/a.png"))
    page = write(Path("out/report.html"), "Campaign", [*sections(fig), Section("Abs", [Figure(fig.resolve())])])
    text = page.read_text()
    assert text.count('src="figs/a.png"') == 2 and 'src="out/' not in text
    check = open_elsewhere(page)
    assert check.images == 2 and check.images_loaded == 2 and check.ok


def _health_dir(tmp_path: Path, runs: dict[str, list[dict[str, Any]]]) -> Path:
    (tmp_path / "health").mkdir(parents=True)
    for stage, rows in runs.items():
        full = [
            {"log": f"{stage}{k}.h5", "status": "completed", "reason": None, "samples": 100, "late_samples": 0}
            | {"gaps": 0, "max_gap_s": 1.0, "safety_events": []}
            | r
            for k, r in enumerate(rows)
        ]
        (tmp_path / "health" / f"{stage}.json").write_text(json.dumps(full))
    return tmp_path


def test_the_run_log_headline_is_green_only_when_every_run_completed_on_time(tmp_path: Path) -> None:
    aborted = {"status": "aborted", "reason": "cell model: step did not converge at t = 237583.0 s"}
    cases = {
        "clean": ({"ocv": [{}], "noise": [{}, {}]}, "good"),
        "aborted": ({"conventional": [{}, aborted], "validation": [aborted, {}]}, "warn"),
        "late": ({"ocv": [{"late_samples": 3}], "noise": [aborted]}, "bad"),
    }
    for name, (runs, tone) in cases.items():
        section = _health(_health_dir(tmp_path / name, runs))
        head = section.blocks[0]
        assert isinstance(head, Paragraph) and head.tone == tone, (name, head)
    section = _health(tmp_path / "aborted")
    head = section.blocks[0].text  # type: ignore[union-attr]
    assert "2 of 4 runs did not complete" in head
    listed = [b.text for b in section.blocks[1:3]]  # type: ignore[union-attr]
    assert listed[0].startswith("conventional/conventional1.h5 aborted: cell model: step did not converge")
    assert listed[1].startswith("validation/validation0.h5 aborted")
    assert 'class="warn"' in render("t", [section]) and 'class="good"' not in render("t", [section])
