"""The plan file shared by design, lab and identification: a protocol, an optional ``[run]`` table, and the
design's groups read back from the sidecar or from the profile steps' labels."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import tomli_w

from battlab.design.plan import grouped_protocol
from battlab.io.plan import Plan, design_groups, sidecar_path
from battlab.parameters import TABLE9_GROUPS
from protocols import Library
from protocols.errors import InputError
from protocols.protocol import Protocol


@pytest.fixture(scope="module")
def lib() -> Library:
    return Library.build()


def _labelled(lib: Library, groups: dict[int, list[int]]) -> Protocol:
    """The design's grouped protocol: profiles in group order, each step labelled 'group k: …'."""
    return grouped_protocol("plan", [(g, [lib[pid] for pid in ids]) for g, ids in groups.items()], "")


def test_a_plan_with_a_run_table_gives_options_and_groups(tmp_path: Path, lib: Library) -> None:
    data = _labelled(lib, {1: [19], 2: [37]}).to_dict()
    data["run"] = {"repeat": 2, "ambient_degC": 10.0}
    path = tmp_path / "plan.toml"
    path.write_text(tomli_w.dumps(data))
    plan = Plan.load(path)
    assert plan.options.repeat == 2 and plan.options.ambient_degC == 10.0
    groups = design_groups(path)
    assert [g.parameters for g in groups] == [tuple(g) for g in TABLE9_GROUPS]
    assert groups[0].selected == {"19"} and groups[1].selected == {"37"}
    assert all(not g.selected for g in groups[2:])


def test_the_design_sidecar_wins_over_summary_json_and_labels(tmp_path: Path, lib: Library) -> None:
    path = tmp_path / "plan.toml"
    path.write_text(tomli_w.dumps(_labelled(lib, {1: [19, 37]}).to_dict()))
    summary = {"groups": [{"parameters": ["R_s_n"], "selected": [19]}]}
    (tmp_path / "summary.json").write_text(json.dumps({"stages": []}))  # e.g. an old fit's summary in the folder
    assert sidecar_path(path) == tmp_path / "plan.summary.json"
    sidecar_path(path).write_text(json.dumps(summary))
    groups = design_groups(path)
    assert len(groups) == 1 and groups[0].parameters == ("R_s_n",) and groups[0].selected == {"19"}
    sidecar_path(path).write_text(json.dumps({"stages": []}))  # the plan's own summary must be the design's
    with pytest.raises(InputError, match=r"plan\.summary\.json: expected the design summary with 'groups'"):
        design_groups(path)
    sidecar_path(path).unlink()
    # the fixed summary.json of before is another command's when it has no groups: the labels give the groups
    groups = design_groups(path)
    assert groups[0].parameters == tuple(TABLE9_GROUPS[0]) and groups[0].selected == {"19", "37"}


@pytest.mark.parametrize("legacy", ["plan.design.json", "summary.json"])
def test_the_design_summary_s_older_names_are_read(tmp_path: Path, lib: Library, legacy: str) -> None:
    path = tmp_path / "plan.toml"
    path.write_text(tomli_w.dumps(_labelled(lib, {1: [19, 37]}).to_dict()))
    (tmp_path / legacy).write_text(json.dumps({"groups": [{"parameters": ["k_n"], "selected": [37]}]}))
    groups = design_groups(path)
    assert len(groups) == 1 and groups[0].parameters == ("k_n",) and groups[0].selected == {"37"}


def test_a_bad_run_table_names_the_file_and_field(tmp_path: Path, lib: Library) -> None:
    data = _labelled(lib, {1: [19]}).to_dict()
    data["run"] = {"repeats": 2}
    path = tmp_path / "plan.toml"
    path.write_text(tomli_w.dumps(data))
    with pytest.raises(InputError, match=r"plan\.toml: \[run\] unknown field\(s\) \['repeats'\]"):
        design_groups(path)
