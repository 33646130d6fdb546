"""Experiments that decide: the options are checked before anything runs (one line, exit 2), the candidates are the
library profiles of the kinds the causes' evidence names, and the fitted models come from the diagnosis's fits."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from battlab.campaign.decide import DecideOptions, candidate_profiles, fitted_models
from battlab.cli import main
from battlab.diagnose.confirmation import Confirmation
from battlab.diagnose.workflow import DiagnoseOptions
from protocols.errors import InputError


def test_decide_options_are_checked_before_anything_runs(tmp_path: Path) -> None:
    d = DiagnoseOptions(("a.csv",), "nca18650")
    with pytest.raises(InputError, match="needs its hidden cell: --truth"):
        DecideOptions(d, tmp_path)
    with pytest.raises(InputError, match="as 'virtual' or both as URLs"):
        DecideOptions(d, tmp_path, cycler="socket://127.0.0.1:5025", chamber="virtual")
    with pytest.raises(InputError, match="--budget-hours 0"):
        DecideOptions(d, tmp_path, truth="nca18650-true", budget_hours=0.0)


def test_the_cli_refuses_a_bad_ambient_list_in_one_line(tmp_path: Path) -> None:
    csv = tmp_path / "x.bdf.csv"
    csv.write_text("Test Time / s,Voltage / V,Current / A\n0,3.6,0\n")
    r = CliRunner().invoke(
        main, ["diagnose", str(csv), "--cell", "nca18650", "--decide", "--ambients", "ten", "-o", str(tmp_path / "rep")]
    )
    assert r.exit_code == 2 and "--ambients 'ten'" in r.output and "Traceback" not in r.output


def test_candidates_follow_the_evidence_and_models_the_fits() -> None:
    from battlab import Cell

    profiles = candidate_profiles(["contact_resistance", "kinetics"])
    assert profiles and all(p.kind == "pulse" for p in profiles) and len(profiles) <= 12
    cell = Cell.load("nca18650")

    class Report:
        confirmations = [
            Confirmation("contact_resistance", ("contact_resistance.R_c",), {"contact_resistance.R_c": 0.002}, 0, 1, 1),
            Confirmation("kinetics", ("R_f_n",), {"R_f_n": 8e-4}, 0, 1, 1),
        ]

    models = fitted_models(Report(), ["contact_resistance", "kinetics"], cell)  # type: ignore[arg-type]
    assert models["contact_resistance"][0].value("contact_resistance.R_c") == 0.002
    assert models["kinetics"][0]["R_f_n"] == 8e-4 and not models["kinetics"][0].extensions


def test_the_first_diagnosis_holds_out_what_its_options_say(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A decided diagnosis held out the last file whatever ``held_out`` said (the campaign's drive cycle by luck of
    order); when the data already tell, the first diagnosis is the only one and uses the options' held-out data."""
    import battlab.campaign.decide as D

    seen = []

    class Report:
        summary = {"cause": None, "cannot_tell": [], "ranking": []}

    def diagnose(options: DiagnoseOptions, subscribers: object = ()) -> Report:
        seen.append(options.held_out)
        return Report()

    monkeypatch.setattr(D, "diagnose", diagnose)
    d = DiagnoseOptions(("a.csv", "b.csv", "c.csv"), "nca18650", held_out="a.csv")
    D.decide(DecideOptions(d, tmp_path, truth="nca18650-true"))
    assert seen == [("a.csv",)]
