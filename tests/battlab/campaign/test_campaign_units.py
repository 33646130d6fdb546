"""Campaign stages are declared units: a stage receives only the settings it declares (reading another fails at
once, never a stale rerun key), its rerun key holds exactly those settings, it may write only the file roles it
declares, and every stage of the pipeline reads what its declaration says."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from battlab.campaign import pipeline
from battlab.campaign.config import CampaignConfig
from battlab.campaign.stages import StageContext, StageOutput, run_stages, stage_key
from battlab.campaign.tester import Tester
from battlab.campaign.unit import UndeclaredSetting, Unit


def _camp(tmp_path: Path, config: CampaignConfig | None = None) -> pipeline.Campaign:
    return pipeline.Campaign(
        config or CampaignConfig(), Tester("socket://127.0.0.1:1", "modbus-tcp://127.0.0.1:2"), tmp_path
    )


def _unit(reads: tuple[str, ...], read: str, outputs: tuple[str, ...] = ("out",)) -> Unit:
    def make(camp):  # noqa: ANN001, ANN202
        def run(ctx: StageContext) -> StageOutput:
            value = getattr(camp.config, read)
            (ctx.directory / "out.txt").write_text(str(value))
            return StageOutput({"out": "out.txt"}, {"read": str(value)})

        return run

    return Unit("probe", "probe", make, reads=reads, outputs=outputs)


def test_a_stage_that_reads_an_undeclared_setting_fails_at_once(tmp_path: Path) -> None:
    camp = _camp(tmp_path)
    ok = _unit(("fit",), "fit").stage(camp, ())
    assert ok.settings == {"fit": CampaignConfig().as_dict()["fit"]}  # its rerun key: exactly what it reads
    run_stages(tmp_path / "a", [ok], {"id": 1})
    sneaky = _unit(("fit",), "design").stage(camp, ())
    with pytest.raises(UndeclaredSetting, match=r"'probe' reads \[design\] without declaring it"):
        run_stages(tmp_path / "b", [sneaky], {"id": 1})


def test_the_rerun_key_changes_with_a_declared_setting_only(tmp_path: Path) -> None:
    base = CampaignConfig()
    unit = _unit(("fit",), "fit")
    key = stage_key(unit.stage(_camp(tmp_path, base), ()), {})
    more = replace(base, fit=replace(base.fit, max_evaluations=99))
    other = replace(base, design=replace(base.design, criterion="A"))
    assert stage_key(unit.stage(_camp(tmp_path, more), ()), {}) != key
    assert stage_key(unit.stage(_camp(tmp_path, other), ()), {}) == key


def test_a_stage_may_write_only_its_declared_file_roles(tmp_path: Path) -> None:
    stage = _unit(("fit",), "fit", outputs=("summary",)).stage(_camp(tmp_path), ())
    with pytest.raises(UndeclaredSetting, match=r"undeclared file roles \['out'\]"):
        run_stages(tmp_path / "c", [stage], {"id": 1})


def test_every_unit_of_the_pipeline_is_declared_whole() -> None:
    names = [u.name for u in pipeline.UNITS]
    assert len(set(names)) == len(names) and names[-1] == "report"
    for u in pipeline.UNITS:
        assert u.title and u.outputs, u.name
        assert all(n in names[: names.index(u.name)] for n in u.needs), u.name
        if u.uses_tester:
            assert "campaign" in u.reads, f"{u.name}: a run on the tester reads the cell's rating and the ambient"
