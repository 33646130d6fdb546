"""``battlab validate``: its page shows its figures wherever it is opened from."""

from __future__ import annotations

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
