"""The campaign report's run-log health: green only when every run completed without late samples or gaps; runs
that did not complete are named, in the health section and in the results box."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from battlab.campaign.report import health_rows, health_section, results_box
from battlab.report import Paragraph, render

ABORTED = {"status": "aborted", "reason": "cell model: step did not converge at t = 237583.0 s"}


def _health(directory: Path, runs: dict[str, list[dict[str, Any]]]) -> list[list[Any]]:
    (directory / "health").mkdir(parents=True)
    for stage, rows in runs.items():
        full = [
            {"log": f"{stage}{k}.h5", "status": "completed", "reason": None, "samples": 100, "late_samples": 0}
            | {"gaps": 0, "max_gap_s": 1.0, "safety_events": [] if not r else [r.get("reason", "")]}
            | r
            for k, r in enumerate(rows)
        ]
        (directory / "health" / f"{stage}.json").write_text(json.dumps(full))
    return health_rows(directory)


@pytest.mark.parametrize(
    ("runs", "green"),
    [
        ({"ocv": [{}], "noise": [{}, {}]}, True),
        ({"conventional": [{}, ABORTED], "validation": [ABORTED, {}]}, False),
        ({"ocv": [{"late_samples": 3}]}, False),
        ({"ocv": [{"gaps": 1}]}, False),
    ],
)
def test_the_run_log_headline_is_green_only_when_every_run_completed_on_time(
    tmp_path: Path, runs: dict[str, list[dict[str, Any]]], green: bool
) -> None:
    section = health_section(_health(tmp_path, runs))
    head = section.blocks[0]
    assert isinstance(head, Paragraph) and (head.tone == "good") == green, head
    assert ('class="good"' in render("t", [section])) == green


def test_runs_that_did_not_complete_are_named(tmp_path: Path) -> None:
    rows = _health(tmp_path, {"conventional": [{}, ABORTED], "validation": [ABORTED, {}]})
    head = health_section(rows).blocks[0].text  # type: ignore[union-attr]
    assert "4 runs" in head and "2 did not complete" in head
    assert "conventional1.h5: aborted" in head and "validation0.h5: aborted" in head
    box = render("t", [results_box({"fit": {"converged": True, "s2": 1.0, "parameters": {}}}, rows)])
    assert "2 of 4 runs did not complete" in box and 'class="good"' not in box
