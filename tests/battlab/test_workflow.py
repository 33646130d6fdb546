"""The workflow API from Python: each step returns the values the command line prints and writes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import battlab
from battlab import parameters as P
from battlab import workflow
from battlab.identify.forward import ForwardModel
from battlab.identify.virtual import synthesize
from battlab.io.bdf import write_bdf_csv
from battlab.io.data import CURRENT, TIME, VOLTAGE, LoggedData
from protocols import Library

IDS = [28, 37, 136, 541, 553, 583]  # 600 s profiles (pulses and sines from four start SOCs)


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("wf")
    Library.build().save(d / "library.h5")
    events = []
    rep = workflow.sweep(
        d / "library.h5", "nca18650", d / "sens.h5", ids=IDS, conventional=False, workers=1, subscribers=[events.append]
    )
    assert (rep.total, rep.computed, rep.ok + rep.flagged + rep.failed) == (6, 6, 6)
    kinds = [e.kind for e in events]
    assert kinds[0] == "start" and kinds[-1] == "stop" and kinds.count("advance") == 6
    assert events[-2].done == events[-2].total == 6
    return d / "sens.h5"


def test_groups_returns_ranking_groups_and_writes_them(store: Path) -> None:
    rep = workflow.groups(store, k=4, perturb=False)
    assert sorted(n for g in rep.groups for n in g) == sorted(rep.info.names)
    assert len(rep.groups) == 4 and rep.weighted
    written = json.loads(rep.path.read_text())
    assert written["groups"] == rep.groups
    assert [Path(f).is_file() for f in rep.figures] == [True]


def test_design_returns_the_selection_it_writes(store: Path, tmp_path: Path) -> None:
    rep = workflow.design(store, tmp_path / "plan.toml", M=2, k=2)
    assert len(rep.designs) == 2 and all(len(d.selected) == 2 for d in rep.designs)
    summary = json.loads(rep.files.summary.read_text())
    assert [g["selected"] for g in summary["groups"]] == [list(d.selected) for d in rep.designs]
    assert rep.figure.is_file() and rep.n_candidates >= 1 and rep.solve_seconds > 0


def _virtual_csv(tmp_path: Path, pid: int, seed: int) -> str:
    cell = battlab.Cell.load("nca18650")
    truth = cell.with_values(R_s_n=P.SPECS["R_s_n"].truth, R_s_p=P.SPECS["R_s_p"].truth)
    prof = Library.build()[pid]
    e = synthesize(ForwardModel(cell), truth, prof, prof.soc0, seed=seed)
    data = LoggedData(f"p{pid}", {TIME: prof.t, VOLTAGE: e.voltage, CURRENT: prof.current}, {"soc0": prof.soc0})
    return str(write_bdf_csv(data, tmp_path / f"p{pid}.bdf.csv"))


def test_fit_and_validate_return_what_they_write(tmp_path: Path) -> None:
    a, b = _virtual_csv(tmp_path, 19, 1), _virtual_csv(tmp_path, 37, 2)
    stages = []
    rep = workflow.fit([a], "nca18650", params="R_s_n,R_s_p", on_stage=lambda k, r: stages.append(k))
    assert stages == [1] and rep.summary["converged"] is True
    assert rep.cell["R_s_n"] == rep.summary["parameters"]["R_s_n"]["value"]
    bpx, summary = rep.write(tmp_path / "cell.bpx.json")
    assert json.loads(summary.read_text())["parameters"]["R_s_p"]["value"] == rep.cell["R_s_p"]
    assert battlab.Cell.from_bpx(bpx)["R_s_p"] == rep.cell["R_s_p"]
    val = workflow.validate([b], ["nca18650", str(bpx)])
    assert val.table["cell"]["p37"] < val.table["nca18650"]["p37"]
    assert np.isfinite(val.errors["cell"]).all()
    assert json.loads(val.write(tmp_path / "v").read_text())["rmse_mV"] == val.table
