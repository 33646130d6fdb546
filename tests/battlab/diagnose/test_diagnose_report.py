"""The diagnosis report's rendering: the verdict's words and colour follow the summary's numbers (never green with a
residual far above the noise), a cause the data cannot test is never shown as passing, and the page written into a
relative directory shows its figures when opened from another one."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from battlab.diagnose.confirm import S2_REFIT
from battlab.diagnose.report import DiagnosisReport, headline
from battlab.diagnose.residuals import analyse
from battlab.report.browser import PageCheck

THERMAL = {
    "cause": "thermal",
    "why": "one ambient temperature: activation energies are seen only through a change of temperature",
    "kind": "pulse",
    "experiment": "the same profile at another ambient",
}


def summary(**changes: Any) -> dict[str, Any]:
    """A diagnosis summary as the workflow writes it: no cause, a residual 4e4 × the noise, thermal passing its
    score test on one ambient (so also listed as not testable)."""
    rows = [
        {"cause": "thermal", "score": 40.0, "dof": 3, "p_value": 1e-9, "projected": 0.4, "passes": True},
        {"cause": "hysteresis", "score": 1.1, "dof": 2, "p_value": 0.3, "projected": 0.8, "passes": False},
    ]
    base: dict[str, Any] = {
        "cause": None,
        "cannot_tell": [],
        "untestable": [THERMAL],
        "undetectable": [],
        "ranking": [r | {"mimicked_by": []} for r in rows],
        "extension_gain": {"rmse_before_mV": 44.0, "rmse_after_mV": None, "held_out": "d (final 30 %)"},
        "verdict": "score tests passed (thermal) but no fitted extension lowered the held-out RMSE by 30 %",
        "threshold": {"p_value": 0.005, "rule": "Bonferroni"},
        "indistinguishable": [],
        "residual_over_noise": 4.0e4,
        "data": ["d"],
        "held_out": "d (final 30 %)",
        "seconds": 12.0,
    }
    return base | changes


def report(s: dict[str, Any]) -> DiagnosisReport:
    t = np.arange(600.0)
    current = 2.0 * np.sign(np.sin(t / 50.0))
    measured = 3.7 + 0.002 * np.sin(t / 30.0) + 1e-4 * np.random.default_rng(0).standard_normal(t.size)
    a = analyse(t, measured, np.full(t.size, 3.7), current, noise_variance=1e-8)
    return DiagnosisReport(s | {"residual": a.summary()}, a, [], [], None, "nca18650")


@pytest.mark.parametrize(
    ("changes", "tone", "words"),
    [
        ({}, "bad", "no cause named, but the model is wrong here: residual s² 4e+04 over the noise variance"),
        ({"cause": "hysteresis"}, "bad", "cause: hysteresis"),
        ({"cause": "hysteresis", "residual_over_noise": 1.1}, "bad", "cause: hysteresis (residual s² 1.1 over"),
        ({"residual_over_noise": 1.1}, "good", "no significant discrepancy among the causes tested"),
        ({"residual_over_noise": 1.1, "cannot_tell": [{"cause": "thermal"}]}, "warn", "cannot tell thermal"),
        ({"residual_over_noise": None}, "warn", "no cause named (noise level unknown)"),
        ({"residual_over_noise": 0.999 * S2_REFIT}, "good", "no significant discrepancy"),
        ({"residual_over_noise": 1.001 * S2_REFIT}, "bad", "the model is wrong here"),
    ],
)
def test_the_verdict_and_its_colour_follow_the_numbers(changes: dict[str, Any], tone: str, words: str) -> None:
    text, got = headline(summary(**changes))
    assert got == tone and words in text, text
    if tone != "good":
        assert "no significant discrepancy" not in text


def test_a_cause_the_data_cannot_test_is_not_shown_as_passing(tmp_path: Path) -> None:
    rep = report(summary())
    line = next(x for x in rep.text().splitlines() if "thermal" in x and "dof" in x)
    assert line.startswith("   thermal") and line.endswith("not testable here")  # no "*" mark
    page = rep.write(tmp_path / "out").read_text()
    row = page[page.index("<td>thermal</td>") :].split("</tr>")[0]
    assert "<td>not testable here</td>" in row and "<td>yes</td>" not in row
    assert "not testable here: thermal (one ambient temperature" in page


def test_a_residual_far_above_the_noise_is_never_green_on_the_page(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, open_elsewhere: Callable[[Path], PageCheck]
) -> None:
    """Written as `battlab diagnose ... -o diag` writes it, opened in Chromium from another working directory."""
    monkeypatch.chdir(tmp_path)
    page = report(summary()).write("diag")
    text = page.read_text()
    assert 'class="good"' not in text and "no significant discrepancy" not in text
    assert '<p class="bad">no cause named, but the model is wrong here' in text
    assert 'src="diag/' not in text and 'src="residual.png"' in text
    check = open_elsewhere(page)
    assert check.images == 3 and check.images_loaded == 3 and check.ok
