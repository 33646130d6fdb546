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


def test_the_results_box_is_green_only_for_fits_whose_intervals_carry_no_caveat(tmp_path: Path) -> None:
    rows = _health(tmp_path, {"ocv": [{}]})
    clean = {"converged": True, "s2": 1.1, "parameters": {}, "trust": {"caveats": [], "trusted": ["R_s_n"]}}
    assert 'class="good"' in render("t", [results_box({"fit": clean}, rows)])
    why = "the residual is correlated from sample to sample (lag-1 autocorrelation 0.12; white noise: 0 ± 0.01)"
    correlated = clean | {"trust": {"caveats": [why], "trusted": [], "untrusted": ["R_s_n"]}}
    box = render("t", [results_box({"fit": correlated}, rows)])
    assert 'class="good"' not in box and "read with care" in box and "lag-1 autocorrelation 0.12" in box


def test_the_equilibrium_section_says_when_its_intervals_cannot_be_trusted(tmp_path: Path) -> None:
    from battlab.campaign.report import View, equilibrium

    row = {"truth": 0.5439, "estimate": 0.542, "bias": -0.0035, "ci95": [0.541, 0.543], "covered": False}
    summary = {"converged": False, "untrusted_because": ["the equilibrium fit did not converge (4 simulations)"]}
    summaries = {"equilibrium": summary | {"truth": {"eps_s_n": row | {"trusted": False}}}}
    view = View(tmp_path, summaries, {}, None, tmp_path)
    html = render("t", [equilibrium(view)])
    assert "<th>trusted</th>" in html and "intervals not to be trusted: the equilibrium fit did not converge" in html


def test_the_diagnosis_section_shows_each_cause_extended_and_the_one_kept(tmp_path: Path) -> None:
    from battlab.campaign.report import View, diagnosis

    tried = [
        {"cause": "current_sensor", "rmse_before_mV": 3.05, "rmse_after_mV": 8.81, "cell": "x", "kept": False},
        {"cause": "hysteresis", "rmse_before_mV": 20.91, "rmse_after_mV": 5.71, "cell": "y", "kept": True},
    ]
    table = {"before": {"1C discharge": 39.31}, "after": {"1C discharge": 10.74}}
    dg = {"cause": "hysteresis", "verdict": "v", "extended": tried, "validation_rmse_mV": table}
    dg["extension_gain"] = {"cause": "hysteresis", "rmse_before_mV": 20.91, "rmse_after_mV": 5.71}
    html = render("t", [diagnosis(View(tmp_path, {"diagnosis": dg}, {}, None, tmp_path))])
    assert "causes extended (extend step)" in html and "<td>current_sensor</td>" in html
    assert "before and after the hysteresis extension" in html
    # nothing kept: the caption names the cause extended, not None
    dg0 = dg | {"cause": None, "extended": tried[:1], "extension_gain": {"cause": "current_sensor"}}
    html = render("t", [diagnosis(View(tmp_path, {"diagnosis": dg0}, {}, None, tmp_path))])
    assert "before and after the current_sensor extension" in html and "None" not in html
    # with the control (the base refitted alone by the same evaluations) beside before and after
    control = {"rmse_oed_mV": 20.91, "rmse_refit_mV": 17.12, "rmse_before_mV": 17.12, "baseline": "base refit"}
    dg1 = dg | {"extended": [tried[0], tried[1] | control]}
    dg1["validation_rmse_mV"] = table | {"refit": {"1C discharge": 33.0}}
    html = render("t", [diagnosis(View(tmp_path, {"diagnosis": dg1}, {}, None, tmp_path))])
    assert "<th>base refit [mV]</th>" in html and "<td>17.12</td>" in html and "<td>33</td>" in html
    assert "beside its base refitted alone by the same evaluations" in html
    # a cause that changes the slow cycle: the equilibrium refitted with it, beside the control's
    eqs = {
        "control": {"rmse_mV": 50.27, "converged": True, "capacity_Ah": 2.968, "fitted": {}},
        "current_sensor": {
            "rmse_mV": 0.0885,
            "converged": True,
            "capacity_Ah": 2.714,
            "fitted": {"current_sensor.offset": [0.01497, 0.0146, 0.0153]},
        },
    }
    html = render("t", [diagnosis(View(tmp_path, {"diagnosis": dg1 | {"equilibrium_refit": eqs}}, {}, None, tmp_path))])
    assert "the equilibrium refitted from the OCV test" in html and "<td>the base alone (control)</td>" in html
    assert "current_sensor.offset 0.01497 [0.0146, 0.0153]" in html and "<td>50.27</td>" in html
