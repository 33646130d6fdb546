"""The static HTML report: escaping, relative figure paths, and a real headless Chromium that renders the page
and loads every image (and notices a missing one)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from battlab.report import Figure, KeyValues, Paragraph, Section, Table, render, write
from battlab.report.browser import PageCheck, check_page


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
