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


def test_a_cause_hidden_behind_another_causes_parameters_is_not_ruled_out_when_it_says_what_separates_them() -> None:
    """``undetectable`` entries hidden behind base parameters: a series resistance taken up by the film resistances
    (owned by the kinetics, which it declares a separating experiment for) is a candidate to decide; one hidden
    behind its own cause's parameters, or only too small, is not."""
    from battlab.campaign.decide import not_ruled_out

    own = {"cause": "electrolyte", "hidden_by": ["D_e_scale", "c_e0"], "typical": {"De_slope": 0.4}}
    small = {"cause": "hysteresis", "typical": {"M_n": 0.01}}
    contact = {"cause": "contact_resistance", "hidden_by": ["R_f_p", "sigma_p"], "typical": {"R_c": 0.005}}
    assert not_ruled_out({"undetectable": [own, small]}) is None
    h = not_ruled_out({"undetectable": [own, small, contact]})
    assert h is not None and (h.cause, h.owner, h.by, h.typical) == (
        "contact_resistance",
        "kinetics",
        ("R_f_p", "sigma_p"),
        {"R_c": 0.005},
    )


def test_a_deciding_experiment_for_a_hidden_cause_is_held_out_by_its_final_part(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The experiment run for a cause not ruled out is added to the data and held out by its final part (the fits
    see its beginning); the second diagnosis names what it names, and no second round follows for the same hidden
    cause."""
    import battlab.campaign.decide as D
    from battlab.design.discriminate import Discrimination, Option

    seen = []
    hidden = {"cause": "contact_resistance", "hidden_by": ["R_f_p"], "typical": {"R_c": 0.005}}

    class Report:
        def __init__(self, summary: dict) -> None:
            self.summary = summary

    def diagnose(options: DiagnoseOptions, subscribers: object = ()) -> Report:
        seen.append((options.held_out, options.held_out_tail))
        first = len(seen) == 1
        named = None if first else "contact_resistance"
        return Report({"cause": named, "cannot_tell": [], "ranking": [], "undetectable": [hidden]})

    option = Option("19", 283.15, 1500.0, 2.5)

    def discriminate(models: dict, profiles: list, ambients: list, **kw: object) -> Discrimination:
        assert set(models) == {"contact_resistance", "kinetics"} and kw["anchor"] == 298.15
        return Discrimination(tuple(models), option, (option,))

    monkeypatch.setattr(D, "diagnose", diagnose)
    monkeypatch.setattr("battlab.design.discriminate.discriminate", discriminate)
    monkeypatch.setattr(D, "run_experiment", lambda o, p, a, rel, cell: tmp_path / f"{rel}.h5")
    d = DiagnoseOptions(("a.csv", "b.csv"), "nca18650", held_out="b.csv")
    out = D.decide(D.DecideOptions(d, tmp_path, truth="nca18650-true"))
    assert seen == [(("b.csv",), False), ((tmp_path / "decide_1_19.h5",), True)]
    assert out.undecided is None and out.report.summary["cause"] == "contact_resistance"
    (r,) = out.rounds
    assert r["not_ruled_out"]["cause"] == "contact_resistance" and r["cause_after"] == "contact_resistance"
    assert r["experiment"]["ambient_degC"] == pytest.approx(10.0)
