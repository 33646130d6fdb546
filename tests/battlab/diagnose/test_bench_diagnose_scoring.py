"""How ``benchmarks/bench_diagnose.py`` scores a diagnosis: the outcome read from a summary, visibility from the
oracle's held-out gain, and the two rates (strict and visibility-scored) both printed. Rows are made by hand: no
simulation."""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))

import bench_diagnose as bench  # noqa: E402


def row(truth: str, outcome: str, oracle: float | None, ambients: tuple[float, ...] = (25.0,)) -> dict:
    return {
        "case": 0,
        "truth": truth,
        "outcome": outcome,
        "oracle_gain": oracle,
        "ambients": list(ambients),
        "held_out_gain": None,
        "seconds": 1.0,
    }


def test_a_hidden_cause_listed_as_too_small_to_see_is_cannot_tell_and_another_cause_is_not() -> None:
    s = {"cause": None, "cannot_tell": [], "untestable": [], "undetectable": [{"cause": "capacity_fade"}]}
    assert bench.outcome(s, "capacity_fade") == "cannot tell"
    assert bench.outcome(s, "electrolyte") == "null"
    assert bench.outcome(s, None) == "null"  # noise only: "too small" of some cause is no answer about it
    assert bench.outcome({**s, "cause": "hysteresis"}, "capacity_fade") == "hysteresis"


def test_visible_cases_must_be_named_invisible_ones_only_not_mistaken() -> None:
    assert bench.right_by_visibility(row("hysteresis", "hysteresis", 0.9))
    assert not bench.right_by_visibility(row("hysteresis", "cannot tell", 0.9))  # visible: must name it
    assert bench.right_by_visibility(row("electrolyte", "null", 0.05))
    assert bench.right_by_visibility(row("electrolyte", "cannot tell", 0.05))
    assert not bench.right_by_visibility(row("electrolyte", "equilibrium", 0.05))
    assert bench.visible(row("null", "null", None)) is None


def test_the_table_prints_the_strict_and_the_visibility_scored_rate() -> None:
    rows = [
        row("hysteresis", "hysteresis", 0.9),
        row("thermal", "null", 0.6, (25.0, 10.0, 40.0)),
        row("thermal", "cannot tell", 0.0),
        row("electrolyte", "null", 0.01),
        row("null", "null", None),
    ]
    text = bench.table(rows)
    assert "STRICT: cause named right 1 (25 %)" in text
    assert "VISIBILITY-SCORED: right 3/4 (75 %)" in text
    assert "thermal@1T" in text  # the one-ambient thermal case is its own row
    assert "null cases: 1; a cause named in 0" in text
