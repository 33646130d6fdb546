"""The campaign's stage runner: skipping unchanged stages, rerunning downstream of a change, resuming, refusing
another campaign's directory."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from battlab.campaign.stages import STATE_FILE, Stage, StageContext, StageOutput, run_stages
from protocols.errors import InputError

IDENTITY = {"truth": "nca18650-true", "start": "nca18650", "version": "test"}


class Counter:
    """Stages that write a file from a setting and their inputs, counting how often each ran."""

    def __init__(self, fail_at: str | None = None) -> None:
        self.runs: list[str] = []
        self.fail_at = fail_at

    def stage(self, name: str, needs: tuple[str, ...] = (), value: int = 0) -> Stage:
        def run(ctx: StageContext) -> StageOutput:
            if name == self.fail_at:
                raise RuntimeError(f"{name} interrupted")
            self.runs.append(name)
            text = f"{name}:{value}:" + ",".join(ctx.path(n, "out").read_text() for n in needs)
            (ctx.directory / f"{name}.txt").write_text(text)
            ctx.progress(1, 1, "written")
            return StageOutput({"out": f"{name}.txt"}, {"value": value}, lab_hours=0.5)

        return Stage(name, run, needs, {"value": value})

    def pipeline(self, a: int = 1, b: int = 2, c: int = 3) -> list[Stage]:
        return [self.stage("a", value=a), self.stage("b", ("a",), b), self.stage("c", ("b",), c)]


def test_second_run_skips_everything(tmp_path: Path) -> None:
    c = Counter()
    first = run_stages(tmp_path / "camp", c.pipeline(), IDENTITY)
    second = run_stages(tmp_path / "camp", c.pipeline(), IDENTITY)
    assert c.runs == ["a", "b", "c"]
    assert [r.status for r in first] == ["ran"] * 3
    assert [r.status for r in second] == ["skipped"] * 3
    assert second[2].output.summary == {"value": 3}
    assert (tmp_path / "camp" / "c.txt").read_text() == "c:3:b:2:a:1:"


def test_a_changed_setting_reruns_that_stage_and_downstream(tmp_path: Path) -> None:
    c = Counter()
    run_stages(tmp_path / "camp", c.pipeline(), IDENTITY)
    c.runs.clear()
    recs = run_stages(tmp_path / "camp", c.pipeline(b=5), IDENTITY)
    assert c.runs == ["b", "c"]
    assert [r.status for r in recs] == ["skipped", "ran", "ran"]
    assert (tmp_path / "camp" / "c.txt").read_text() == "c:3:b:5:a:1:"


def test_an_edited_artefact_reruns_its_stage(tmp_path: Path) -> None:
    c = Counter()
    run_stages(tmp_path / "camp", c.pipeline(), IDENTITY)
    (tmp_path / "camp" / "a.txt").write_text("tampered")
    c.runs.clear()
    run_stages(tmp_path / "camp", c.pipeline(), IDENTITY)
    # a is remade; its content is the same as before, so (content hashes) b and c need not run again
    assert c.runs == ["a"]
    assert (tmp_path / "camp" / "a.txt").read_text() == "a:1:"


def test_an_interrupted_campaign_resumes_at_the_failed_stage(tmp_path: Path) -> None:
    broken = Counter(fail_at="c")
    with pytest.raises(RuntimeError, match="interrupted"):
        run_stages(tmp_path / "camp", broken.pipeline(), IDENTITY)
    state = json.loads((tmp_path / "camp" / STATE_FILE).read_text())
    assert sorted(state["stages"]) == ["a", "b"]
    c = Counter()
    recs = run_stages(tmp_path / "camp", c.pipeline(), IDENTITY)
    assert c.runs == ["c"]
    assert [r.status for r in recs] == ["skipped", "skipped", "ran"]


def test_another_campaigns_directory_is_refused_untouched(tmp_path: Path) -> None:
    run_stages(tmp_path / "camp", Counter().pipeline(), IDENTITY)
    before = {p.name: p.read_bytes() for p in (tmp_path / "camp").iterdir()}
    c = Counter()
    with pytest.raises(InputError, match="another campaign.*truth"):
        run_stages(tmp_path / "camp", c.pipeline(), {**IDENTITY, "truth": "other"})
    assert c.runs == []
    assert {p.name: p.read_bytes() for p in (tmp_path / "camp").iterdir()} == before


def test_a_non_campaign_directory_is_refused(tmp_path: Path) -> None:
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "precious.h5").write_bytes(b"x")
    with pytest.raises(InputError, match="not a campaign directory"):
        run_stages(tmp_path / "data", Counter().pipeline(), IDENTITY)


def test_stages_out_of_order_are_an_error(tmp_path: Path) -> None:
    c = Counter()
    with pytest.raises(InputError, match="needs a"):
        run_stages(tmp_path / "camp", [c.stage("b", ("a",)), c.stage("a")], IDENTITY)


def test_progress_events_in_order(tmp_path: Path) -> None:
    events: list[tuple[str, str]] = []
    run_stages(tmp_path / "camp", Counter().pipeline(), IDENTITY, [lambda e: events.append((e.kind, e.task))])
    assert events == [  # the one progress protocol's kinds (battlab.progress)
        ("start", "a"),
        ("advance", "a"),
        ("stop", "a"),
        ("start", "b"),
        ("advance", "b"),
        ("stop", "b"),
        ("start", "c"),
        ("advance", "c"),
        ("stop", "c"),
    ]
