"""The workflow API from Python: each step returns the values the command line prints and writes."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import battlab
from battlab import workflow
from battlab.io.bdf import write_bdf_csv
from battlab.io.data import AMBIENT, CURRENT, TIME, VOLTAGE, LoggedData
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


def test_design_takes_given_groups_and_a_noise_model(store: Path, tmp_path: Path) -> None:
    """A campaign designs with the groups it chose and the noise model it fitted: a 1 V noise floor weights every
    profile's information down by ~1e6 (q from mV to 1 V), so the groups' log-determinants fall."""
    from battlab.noise import NoiseModel

    groups = [["R_s_n", "D_s_n"], ["k_p", "R_s_p"]]
    paper = workflow.design(store, tmp_path / "a" / "plan.toml", M=2, groups=groups)
    noisy = workflow.design(store, tmp_path / "b" / "plan.toml", M=2, groups=groups, noise=NoiseModel(floor=1.0))
    assert paper.source == noisy.source == "given"
    assert [list(d.parameters) for d in paper.designs] == [groups[0], groups[0] + groups[1]]
    for a, b in zip(paper.designs, noisy.designs, strict=True):
        assert b.logdet < a.logdet - 5.0


def test_fit_and_validate_return_what_they_write(tmp_path: Path, virtual_csv) -> None:
    a, b = virtual_csv(tmp_path, 19, 1), virtual_csv(tmp_path, 37, 2)
    stages = []
    rep = workflow.fit(
        workflow.FitOptions([a], "nca18650", params="R_s_n,R_s_p"), [workflow.on_stage(lambda k, r: stages.append(k))]
    )
    assert stages == [1] and rep.summary["converged"] is True
    assert rep.cell["R_s_n"] == rep.summary["parameters"]["R_s_n"]["value"]
    bpx, summary = rep.write(tmp_path / "cell.bpx.json")
    assert json.loads(summary.read_text())["parameters"]["R_s_p"]["value"] == rep.cell["R_s_p"]
    assert battlab.Cell.from_bpx(bpx)["R_s_p"] == rep.cell["R_s_p"]
    val = workflow.validate([b], ["nca18650", str(bpx)])
    assert val.table["cell"]["p37"] < val.table["nca18650"]["p37"]
    assert np.isfinite(val.errors["cell"]).all()
    assert json.loads(val.write(tmp_path / "v").read_text())["rmse_mV"] == val.table


def _early_stop_csv(tmp_path: Path) -> str:
    """Logged at 3.5 V while 3C is drawn for 25 min from half charge: the model empties the cell on the way."""
    t = np.arange(0.0, 1501.0)
    i = np.where(t < 10, 0.0, -3.0 * 2.7)
    cols = {TIME: t, VOLTAGE: np.full(t.size, 3.5), CURRENT: i, AMBIENT: np.full(t.size, 25.0)}
    return str(write_bdf_csv(LoggedData("drain", cols, {"soc0": 0.5}), tmp_path / "drain.bdf.csv"))


def test_validate_scores_only_what_it_predicts_whatever_the_file_order(tmp_path: Path, virtual_csv) -> None:
    a, b = virtual_csv(tmp_path, 19, 3), _early_stop_csv(tmp_path)
    ab = workflow.validate([a, b], ["nca18650"])
    ba = workflow.validate([b, a], ["nca18650"])
    assert ab.table == ba.table and ab.coverage == ba.coverage
    share = ab.coverage["nca18650"]["drain"]
    assert 0.1 < share < 0.9 and ab.coverage["nca18650"]["p19"] == 1.0
    assert ab.ended_by["nca18650"]["drain"].startswith(("V < ", "surface stoichiometry"))
    e, preds = ab.predictions["drain"]
    p = preds["nca18650"]
    reached = np.isfinite(p)
    assert reached.mean() == share and not reached[-1]  # nothing held flat after the stop
    expected = 1e3 * np.sqrt(np.mean((p[reached] - e.voltage[reached]) ** 2))
    assert ab.table["nca18650"]["drain"] == pytest.approx(expected, rel=1e-12)
    assert any("stopped at" in w and "drain" in w for w in ab.warnings)
    summary = json.loads(ab.write(tmp_path / "v").read_text())
    assert summary["coverage"]["nca18650"]["drain"] == share


def test_data_without_an_ambient_are_refused_unless_it_is_given(tmp_path: Path) -> None:
    t = np.arange(0.0, 601.0)
    cols = {TIME: t, VOLTAGE: np.full(t.size, 3.7), CURRENT: np.where(t < 10, 0.0, -1.0)}
    path = str(write_bdf_csv(LoggedData("noamb", cols, {"soc0": 0.5}), tmp_path / "noamb.bdf.csv"))
    with pytest.raises(battlab.InputError, match=r"noamb\.bdf\.csv: no ambient temperature logged"):
        workflow.validate([path], ["nca18650"])
    with pytest.raises(battlab.InputError, match=r"--ambient other\.csv=…: no data file of that name"):
        workflow.validate([path], ["nca18650"], ambient={"other.csv": 273.15})
    cold = workflow.validate([path], ["nca18650"], ambient={"noamb.bdf.csv": 273.15})
    warm = workflow.validate([path], ["nca18650"], ambient=298.15)
    e_cold, e_warm = cold.predictions["noamb"][0], warm.predictions["noamb"][0]
    assert (e_cold.ambient, e_warm.ambient) == (273.15, 298.15)
    assert cold.table["nca18650"]["noamb"] != warm.table["nca18650"]["noamb"]
