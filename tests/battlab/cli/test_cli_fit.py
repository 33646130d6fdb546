"""``battlab fit`` and ``battlab validate`` from the command line."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

import battlab
from battlab import parameters as P
from battlab.cli import main
from battlab.cli.fit_display import own_reasons
from battlab.io.bdf import write_bdf_csv
from battlab.io.data import CURRENT, TIME, VOLTAGE, LoggedData
from protocols.library import Library


def test_fit_and_validate(tmp_path, virtual_csv) -> None:
    a, b = virtual_csv(tmp_path, 19, 1), virtual_csv(tmp_path, 37, 2)
    out = tmp_path / "cell.bpx.json"
    r = CliRunner().invoke(main, ["fit", a, "--cell", "nca18650", "--params", "R_s_n,R_s_p", "-o", str(out)])
    assert r.exit_code == 0, r.output
    summary = json.loads((tmp_path / "cell.summary.json").read_text())
    assert json.loads((tmp_path / "summary.json").read_text()) == summary  # the contract's name, the same content
    assert set(summary["parameters"]) == {"R_s_n", "R_s_p"} and summary["converged"] is True
    for name, entry in summary["parameters"].items():
        lo, hi = entry["ci95"]
        assert lo <= P.SPECS[name].truth <= hi and entry["at_bound"] is False
    assert summary["rmse_mV"]["p19"] < 10
    corr = summary["stages"][0]["correlation"]
    assert len(corr) == 2 and np.allclose([corr[0][0], corr[1][1]], 1.0) and -1 < corr[0][1] < 1
    assert (tmp_path / "cell.stage1.error_cdf.png").is_file() and (tmp_path / "cell.stage1.correlation.png").is_file()
    assert "95 % interval" in r.output and "R_s_n" in r.output
    fitted = battlab.Cell.from_bpx(out)
    assert fitted["R_s_n"] == summary["parameters"]["R_s_n"]["value"]
    r = CliRunner().invoke(main, ["validate", b, "--cell", "nca18650", "--cell", str(out), "-o", str(tmp_path / "v")])
    assert r.exit_code == 0, r.output
    table = json.loads((tmp_path / "v" / "v.summary.json").read_text())["rmse_mV"]
    assert table["cell"]["p37"] < table["nca18650"]["p37"]
    assert (tmp_path / "v" / "error_cdf.png").is_file() and (tmp_path / "v" / "p37.png").is_file()


def test_bad_input_is_one_line(tmp_path) -> None:
    p = tmp_path / "bad.bdf.csv"
    t = np.arange(10.0)
    v = np.full(10, 3.7)
    v[4] = np.nan
    np.savetxt(
        p, np.column_stack([t, v, np.zeros(10)]), delimiter=",", header=f"{TIME},{VOLTAGE},{CURRENT}", comments=""
    )
    r = CliRunner().invoke(main, ["fit", str(p), "--cell", "nca18650", "-o", str(tmp_path / "c.json")])
    assert r.exit_code == 2
    assert "Voltage / V" in r.output and "sample 4" in r.output and "Traceback" not in r.output


def test_fit_consumes_a_design_plan_summary(tmp_path, virtual_csv) -> None:
    """``--plan``: the groups (parameters, selected profiles) come from the design's plan.summary.json beside it;
    the fit's summary, named after the fitted cell, beside it too, replaces nothing."""
    import tomli_w

    from protocols.concatenate import concatenate

    a, b = virtual_csv(tmp_path, 19, 3), virtual_csv(tmp_path, 37, 4)
    lib = Library.build()
    plan = tmp_path / "plan.toml"
    plan.write_text(tomli_w.dumps(concatenate([lib[19], lib[37]], name="plan").protocol.to_dict()))
    (tmp_path / "plan.summary.json").write_text(
        json.dumps(
            {
                "groups": [
                    {"parameters": ["R_s_n"], "selected": ["p19"], "logdet": 1.0},
                    {"parameters": ["R_s_n", "R_s_p"], "selected": ["p37"], "logdet": 2.0},
                ]
            }
        )
    )
    out = tmp_path / "fitted.json"
    r = CliRunner().invoke(main, ["fit", a, b, "--cell", "nca18650", "--plan", str(plan), "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert "groups" in json.loads((tmp_path / "plan.summary.json").read_text())  # the design's summary is kept
    s = json.loads((tmp_path / "fitted.summary.json").read_text())
    stages = s["stages"]
    assert [st["parameters"] for st in stages] == [["R_s_n"], ["R_s_n", "R_s_p"]]
    assert stages[0]["experiments"] == ["p19"] and stages[1]["experiments"] == ["p19", "p37"]


def test_data_from_another_cell_is_one_line(tmp_path) -> None:
    t = np.arange(0.0, 600.0)
    v = 3.3 - 0.3 * t / 600  # an LFP-like plateau ending at 3.0 V, but starting at rest at 3.3 V
    i = np.where(t > 10, -1.0, 0.0)
    data = LoggedData("lfp", {TIME: t, VOLTAGE: v - 1.2, CURRENT: i}, {})  # 2.1-1.8 V: far below 2.5 V
    p = write_bdf_csv(data, tmp_path / "lfp.bdf.csv")
    r = CliRunner().invoke(
        main, ["fit", str(p), "--cell", "nca18650", "--params", "R_s_n", "-o", str(tmp_path / "c.json")]
    )
    assert r.exit_code == 2 and "Traceback" not in r.output
    assert "leaves cell 'nca18650'" in r.output and "samples 0–599" in r.output and "do not match" in r.output
    data = LoggedData("hv", {TIME: t, VOLTAGE: v + 1.02, CURRENT: i}, {})  # rests at 4.32 V, above OCV(100 %)
    p = write_bdf_csv(data, tmp_path / "hv.bdf.csv")
    r = CliRunner().invoke(
        main, ["fit", str(p), "--cell", "nca18650", "--params", "R_s_n", "-o", str(tmp_path / "c.json")]
    )
    assert r.exit_code == 2 and "rest voltage 4.320 V at sample 0 is outside" in r.output, r.output
    data = LoggedData("lfp", {TIME: t, VOLTAGE: v, CURRENT: i}, {})  # fits nothing like the model: says so
    p = write_bdf_csv(data, tmp_path / "lfp3.bdf.csv")
    args = ["fit", str(p), "--cell", "nca18650", "--params", "R_s_n", "-o", str(tmp_path / "c.json")]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2 and "no ambient temperature logged" in r.output and "lfp3.bdf.csv" in r.output
    r = CliRunner().invoke(main, [*args, "--ambient", "lfp3.bdf.csv=25"])
    assert r.exit_code == 0 and "model error" in r.output, r.output


@pytest.mark.slow
def test_table9_fit_through_stage4_when_a_rate_constant_is_not_determined(tmp_path, virtual_csv) -> None:
    """600 s of 10-s pulses (seed 5) leave k_p without information at stage 4: the fit once ended there with an
    OverflowError from the κ_p interval. It finishes; κ_p's interval is what the bounds allow."""
    a = virtual_csv(tmp_path, 19, 5)
    out = tmp_path / "cell.bpx.json"
    r = CliRunner().invoke(main, ["fit", a, "--cell", "nca18650", "--params", "table9", "-o", str(out)])
    assert r.exit_code == 0, r.output
    s = json.loads((tmp_path / "summary.json").read_text())
    assert [len(st["parameters"]) for st in s["stages"]] == [2, 8, 12, 16]  # R_s held where its orbit is fitted
    kappa = s["stages"][-1]["invariants"]["kappa_p"]
    assert kappa["ci95"] == pytest.approx([2.3e-4 / 1e-4, 2.3e-2 / 1e-6], rel=1e-9)
    assert battlab.Cell.from_bpx(out)["k_p"] == s["parameters"]["k_p"]["value"]


@pytest.mark.parametrize(
    ("stage", "crash", "code"), [(3, RuntimeError("solver diverged\nat t = 12 s"), 1), (2, KeyboardInterrupt(), 130)]
)
def test_a_crash_in_a_stage_keeps_the_finished_stages(tmp_path, virtual_csv, monkeypatch, stage, crash, code) -> None:
    """A crash (or Ctrl-C) in stage k: one line naming the stage and where stages 1..k-1 are, which load."""
    from battlab.identify import fit as F

    real = F.fit

    def fit(*args, **kwargs):  # simulates the crash; everything else runs for real
        if kwargs.get("stage") == stage:
            raise crash
        return real(*args, **kwargs)

    monkeypatch.setattr(F, "fit", fit)
    a = virtual_csv(tmp_path, 19, 1)
    out = tmp_path / "new" / "cell.bpx.json"  # a directory that does not exist yet
    args = ["fit", a, "--cell", "nca18650", "--params", "table9", "--max-iter", "2", "-o", str(out)]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == code, r.output
    assert "Traceback" not in r.output and isinstance(r.exception, SystemExit)
    errors = [line for line in r.output.splitlines() if not line.startswith(("stage ", "  "))]  # not a stage's lines
    kept = "stage 1 of 4" if stage == 2 else f"stages 1–{stage - 1} of 4"
    if code == 1:
        assert errors == [
            f"error: fit failed in stage {stage} of 4: RuntimeError: solver diverged at t = 12 s; "
            f"{kept} kept (partial) in {out} and {out.with_name('cell.summary.json')}"
        ]
    else:
        assert errors == [
            f"interrupted in stage {stage}; {kept} kept (partial) in {out} and {out.with_name('cell.summary.json')}"
        ]
    summary = json.loads(out.with_name("summary.json").read_text())
    assert summary["partial"] is True and summary["status"] == f"partial: {kept}" and summary["converged"] is False
    assert len(summary["stages"]) == stage - 1
    fitted = battlab.Cell.from_bpx(out)
    for name, entry in summary["parameters"].items():
        assert fitted[name] == pytest.approx(entry["value"], rel=1e-12)
    assert (tmp_path / "new" / f"cell.stage{stage - 1}.error_cdf.png").is_file()


def test_groups_is_another_name_for_params(tmp_path, virtual_csv) -> None:
    a = virtual_csv(tmp_path, 19, 1)
    out = tmp_path / "cell.bpx.json"
    r = CliRunner().invoke(
        main, ["fit", a, "--cell", "nca18650", "--groups", "R_s_n", "--max-iter", "2", "-o", str(out)]
    )
    assert r.exit_code == 0, r.output
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert list(summary["parameters"]) == ["R_s_n"] and summary["status"] == "complete: stage 1 of 1"


def test_fit_says_how_good_it_is_and_how_far_to_trust_it(tmp_path, virtual_csv) -> None:
    """The terminal gives each data file's RMSE before -> after against its noise, what to do when a stage stops at
    its limit, the estimates with their units, and a last line with the answer; an unconverged fit's intervals are
    marked untrusted in the summary, with why."""
    a = virtual_csv(tmp_path, 19, 1)
    out = tmp_path / "cell.bpx.json"
    r = CliRunner().invoke(
        main, ["fit", a, "--cell", "nca18650", "--params", "R_s_n,D_s_p", "--max-iter", "2", "-o", str(out)]
    )
    assert r.exit_code == 0, r.output
    assert "RMSE before -> after [mV]" in r.output and "noise [mV]" in r.output
    assert "stopped at its limit of 2 evaluations" in r.output and "--max-iter 4" in r.output
    assert "2 evaluations, NOT converged: maximum number of iterations reached; " in r.output, r.output
    assert "NOT converged; not converged" not in r.output
    assert "m2/s" in r.output and "trusted" in r.output
    last = r.output.strip().splitlines()[-2]
    assert last.startswith("fit NOT converged: RMSE") and "of 2 intervals trusted" in last, r.output
    # what holds for every interval is said once under the table (and in the last line), not on each row
    table = r.output[r.output.index("identified parameters") : r.output.index(last)]
    assert table.count("the fit did not converge") == 1 and "every interval above: the fit did not" in table, table
    summary = json.loads((tmp_path / "summary.json").read_text())
    for name in ("R_s_n", "D_s_p"):
        p = summary["parameters"][name]
        assert p["trusted"] is False and "the fit did not converge" in p["untrusted_because"]
    assert summary["trust"]["trusted"] == [] and "the fit did not converge" in summary["trust"]["caveats"]
    assert set(summary["rmse_before_mV"]) == set(summary["rmse_mV"])


def test_a_row_gives_its_own_reasons_not_the_fits() -> None:
    caveats = ["the fit did not converge"]
    entry = {"untrusted_because": ["the fit did not converge", "at its lower bound (one-sided interval)"]}
    assert own_reasons(entry, caveats) == ["at its lower bound (one-sided interval)"]
    assert own_reasons({"untrusted_because": caveats}, caveats) == [] and own_reasons({}, caveats) == []


@pytest.mark.parametrize(("crash", "code"), [(RuntimeError("solver diverged"), 1), (KeyboardInterrupt(), 130)])
def test_a_crash_in_stage_1_keeps_the_equilibrium_fit(tmp_path, virtual_csv, ocv_csv, monkeypatch, crash, code) -> None:
    """With a C/20 test among the data, the equilibrium fit is printed and written (partial) before stage 1: a crash
    or Ctrl-C there says so in one line, and the files hold the identified stoichiometry windows."""
    from battlab.identify import fit as F

    real = F.fit

    def fit(*args, **kwargs):
        if kwargs.get("stage") == 1:
            raise crash
        return real(*args, **kwargs)

    monkeypatch.setattr(F, "fit", fit)
    out = tmp_path / "cell.bpx.json"
    r = CliRunner().invoke(main, ["fit", ocv_csv, virtual_csv(tmp_path, 19, 1), "--cell", "nca18650", "-o", str(out)])
    assert r.exit_code == code, r.output
    assert "Traceback" not in r.output and isinstance(r.exception, SystemExit)
    lines = r.output.splitlines()
    assert lines[0].startswith("equilibrium (c20): capacity ") and len(lines) == 2
    kept = f"equilibrium only (stages 0 of 4) kept (partial) in {out} and {tmp_path / 'cell.summary.json'}"
    if code == 1:
        assert lines[1] == f"error: fit failed in stage 1 of 4: RuntimeError: solver diverged; {kept}"
    else:
        assert lines[1] == f"interrupted in stage 1; {kept}"
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["status"] == "partial: equilibrium only (stages 0 of 4)" and summary["stages_done"] == 0
    fitted, start = battlab.Cell.from_bpx(out), battlab.Cell.load("nca18650")
    for name in ("eps_s_n", "eps_s_p", "n_Li"):
        assert fitted[name] == pytest.approx(summary["parameters"][name]["value"], rel=1e-12)
    assert f"eps_s_n {fitted['eps_s_n']:.4f}" in lines[0] and fitted["eps_s_n"] != pytest.approx(start["eps_s_n"])


def test_an_ocv_test_alone_is_a_complete_equilibrium_fit(tmp_path, ocv_csv) -> None:
    out = tmp_path / "cell.bpx.json"
    r = CliRunner().invoke(main, ["fit", ocv_csv, "--cell", "nca18650", "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert r.output.startswith("equilibrium (c20): capacity ")
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert (summary["partial"], summary["status"], summary["stages_done"], summary["stages"]) == (
        False,
        "complete: equilibrium only",
        0,
        [],
    )
    assert summary["converged"] is True and set(summary["parameters"]) == {"eps_s_n", "eps_s_p", "n_Li"}


def test_fit_with_an_extension_keeps_it_in_the_cell(tmp_path, virtual_csv) -> None:
    """--extension switches a catalog extension on in the start cell; its KEY.NAME is fitted like the 18 and the
    fitted BPX cell carries it (from the nominal start the series resistance absorbs part of the other parameters'
    mismatch: no claim on its value here)."""
    a = virtual_csv(tmp_path, 19, 1)
    out = tmp_path / "cell.bpx.json"
    args = ["fit", a, "--cell", "nca18650", "--params", "R_s_n,contact_resistance.R_c", "--extension"]
    r = CliRunner().invoke(main, [*args, "contact_resistance:R_c=0.002", "-o", str(out)])
    assert r.exit_code == 0, r.output
    summary = json.loads((tmp_path / "cell.summary.json").read_text())
    entry = summary["parameters"]["contact_resistance.R_c"]
    assert entry["value"] != 0.002 and entry["ci95"][0] < entry["value"] < entry["ci95"][1]
    fitted = battlab.Cell.from_bpx(out)
    assert fitted.extensions["contact_resistance"]["R_c"] == pytest.approx(entry["value"])


def test_fit_with_a_bad_extension_is_one_line(tmp_path, virtual_csv) -> None:
    a = virtual_csv(tmp_path, 19, 1)
    args = ["fit", a, "--cell", "nca18650", "--extension", "contact_resistance:Rc=1", "-o", str(tmp_path / "c.json")]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2 and "--extension 'contact_resistance:Rc=1'" in r.output and "Traceback" not in r.output


def test_a_run_log_is_fitted_in_its_plans_groups(tmp_path, run_log) -> None:
    """`fit RUN.h5 --plan plan.toml` (a plan with a [run] table): each profile step of the log is an experiment of
    its own, and the design's groups (the library ids each selected) are the stages."""
    log, plan = run_log(tmp_path / "run.h5")
    assert "[run]" in plan.read_text()
    groups = [{"parameters": ["R_s_n"], "selected": [28]}, {"parameters": ["R_s_p"], "selected": [37]}]
    (tmp_path / "plan.summary.json").write_text(json.dumps({"groups": groups}))
    out = tmp_path / "fitted.json"
    args = ["fit", str(log), "--cell", "nca18650", "--plan", str(plan), "--max-iter", "2", "-o", str(out)]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 0, r.output
    stages = json.loads((tmp_path / "fitted.summary.json").read_text())["stages"]
    assert [st["parameters"] for st in stages] == [["R_s_n"], ["R_s_n", "R_s_p"]]
    assert [st["experiments"] for st in stages] == [["run:28"], ["run:28", "run:37"]]


def test_fit_says_which_noise_model_weighed_it_and_takes_one_from_a_file(tmp_path, virtual_csv) -> None:
    """Without repeated trials the paper's coefficients weigh the fit, and the output and the summary say so;
    `--noise noise.toml` weighs it by the file's model (s² scales with 1/q²); a bad file is one line."""
    from battlab.noise import NoiseModel, save

    a = virtual_csv(tmp_path, 19, 1)
    args = ["fit", a, "--cell", "nca18650", "--params", "R_s_n", "--max-iter", "3"]
    r = CliRunner().invoke(main, [*args, "-o", str(tmp_path / "p.json")])
    assert r.exit_code == 0, r.output
    paper = json.loads((tmp_path / "p.summary.json").read_text())
    assert paper["noise"]["source"].startswith("the paper's eq. 38 coefficients") and paper["noise"]["trials"] == []
    assert "noise model: the paper's eq. 38 coefficients" in r.output
    noise = save(NoiseModel(0.0, 1e-3, 1e-3, 0.0, 1e-5), tmp_path / "noise.toml")
    r = CliRunner().invoke(main, [*args, "--noise", str(noise), "-o", str(tmp_path / "f.json")])
    assert r.exit_code == 0, r.output
    given = json.loads((tmp_path / "f.summary.json").read_text())
    assert given["noise"]["source"] == f"file {noise}" and given["noise"]["model"]["b_c"] == 1e-3
    assert f"noise model: file {noise}" in r.output
    assert given["stages"][0]["s2"] != pytest.approx(paper["stages"][0]["s2"], rel=0.1)
    (tmp_path / "bad.toml").write_text("[model]\na_c = 1\n")
    r = CliRunner().invoke(main, [*args, "--noise", str(tmp_path / "bad.toml"), "-o", str(tmp_path / "b.json")])
    assert r.exit_code == 2 and "bad.toml: model: missing" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "b.json").exists()


def test_an_ocp_curve_that_is_not_one_is_one_line_before_any_data_is_read(tmp_path) -> None:
    """``battlab fit --ocp``: a wrong electrode or a broken half-cell file is one line naming the option and the
    file, exit code not 0, nothing written."""
    curve = tmp_path / "p.csv"
    curve.write_text("sto,ocp\n0.1,4.1\n0.2,x\n0.3,4.0\n0.4,3.9\n0.5,3.8\n")
    data = tmp_path / "data.csv"
    data.write_text("Test Time / s,Current / A,Voltage / V\n0,0,3.7\n1,0,3.7\n")
    out = tmp_path / "fit.bpx.json"
    for spec, what in ((f"q={curve}", "expected E=FILE"), (f"p={curve}", "line 3: not two numbers")):
        result = CliRunner().invoke(main, ["fit", str(data), "--cell", "nca18650", "--ocp", spec, "-o", str(out)])
        assert result.exit_code != 0
        text = result.output.strip()
        assert len(text.splitlines()) == 1 and "--ocp" in text and what in text, text
    assert not out.exists()


def test_a_measurement_is_fitted_after_its_logged_preparation(tmp_path, prepared_measurement) -> None:
    prep, meas = prepared_measurement(tmp_path)
    out = tmp_path / "c.bpx.json"
    args = ["fit", str(meas), "--cell", "nca18650", "--params", "R_f_n", "--max-iter", "2", "-o", str(out)]
    r = CliRunner().invoke(main, [*args, "--preparation", f"{meas}={prep}"])
    assert r.exit_code == 0, r.output
    summary = json.loads((tmp_path / "c.summary.json").read_text())
    # fitted from the full charge (SOC 1 - 0.01 at most) before the 0.54 Ah adjustment, not from SOC 0.8 at rest
    (soc,) = summary["start_soc"].values()
    assert 0.99 - 1e-9 <= soc <= 1.0


def test_widen_lets_a_cell_of_another_make_leave_the_paper_cells_ranges(tmp_path) -> None:
    """A cell whose electrolyte conducts at 0.3 of the file's (the built-in range stops at 0.5): the fit stops on the
    bound, and with ``--widen`` it finds the value."""
    from battlab.io.data import AMBIENT
    from protocols.profile import Profile

    truth = battlab.Cell.load("nca18650").with_values(kappa_scale=0.3)
    t = np.arange(0.0, 1200.0)
    prof = Profile(t, np.where((t % 200.0) < 60.0, -5.4, 0.0), id="pulses")
    res = battlab.simulate(truth, prof, soc0=0.8, ambient=298.15)
    cols = {TIME: t, VOLTAGE: res.voltage, CURRENT: prof.current, AMBIENT: np.full(t.size, 25.0)}
    p = write_bdf_csv(LoggedData("pulses", cols, {}), tmp_path / "pulses.bdf.csv")
    found = {}
    for widen in ("0", "0.5"):
        out = tmp_path / f"w{widen}.bpx.json"
        args = ["fit", str(p), "--cell", "nca18650", "--params", "kappa_scale", "--soc0", "0.8", "--widen", widen]
        r = CliRunner().invoke(main, [*args, "--max-iter", "12", "-o", str(out)])
        assert r.exit_code == 0, r.output
        found[widen] = float(battlab.Cell.from_bpx(out)["kappa_scale"])
    assert found["0"] == pytest.approx(0.5, abs=1e-3)
    assert found["0.5"] == pytest.approx(0.3, rel=0.02)
    r = CliRunner().invoke(main, ["fit", str(p), "--cell", "nca18650", "--widen", "3", "-o", str(tmp_path / "x.json")])
    assert r.exit_code == 2 and "--widen" in r.output and "Traceback" not in r.output


def test_fit_arrhenius_gives_the_energies_and_how_well_each_refit_fits(tmp_path) -> None:
    """Pulses at 25 and 10 °C of a cell whose E_κ is 15 kJ/mol above the start's: the 10 °C refit and the slope give
    E_κ back, and the terminal says how close each per-temperature refit came to its data (a refit that stays far
    from its data gives a value not worth a slope)."""
    from battlab.io.data import AMBIENT
    from protocols.profile import Profile

    cell = battlab.Cell.load("nca18650")
    truth = cell.with_values(E_kappa=float(cell["E_kappa"]) + 15e3)
    t = np.arange(0.0, 1200.0, 1.0)
    i = np.where((t % 200.0) < 60.0, -2.7, 0.0)
    paths = []
    for amb in (25.0, 10.0):
        res = battlab.simulate(truth, Profile(t, i), soc0=0.8, ambient=273.15 + amb)
        cols = {TIME: t, VOLTAGE: res.voltage, CURRENT: i, AMBIENT: np.full(t.size, amb)}
        paths.append(str(write_bdf_csv(LoggedData(f"pulses{amb:g}", cols, {}), tmp_path / f"p{amb:g}.bdf.csv")))
    out = tmp_path / "cell.bpx.json"
    r = CliRunner().invoke(
        main,
        ["fit", *paths, "--cell", "nca18650", "--soc0", "0.8", "--params", "kappa_scale", "--arrhenius"]
        + ["--max-iter", "6", "-o", str(out)],
    )
    assert r.exit_code == 0, r.output
    assert "activation energies [kJ/mol]: E_kappa 34.7 ->" in r.output, r.output
    refits = next(line for line in r.output.splitlines() if line.startswith("  refits' RMSE [mV]: "))
    assert refits.startswith("  refits' RMSE [mV]: p10 "), refits
    assert float(battlab.Cell.load(str(out))["E_kappa"]) == pytest.approx(float(truth["E_kappa"]), rel=0.1)
