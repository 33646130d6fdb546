"""``battlab.workflow.fit`` keeps each finished stage: written as it finishes, partial until the last."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import battlab
from battlab.identify import fit as F
from battlab.identify import workflow


def crash_in_stage(monkeypatch: pytest.MonkeyPatch, stage: int, exc: BaseException) -> None:
    """Make the fit of ``stage`` raise ``exc`` (a crash, e.g. an overflow, or Ctrl-C); the others run as usual."""
    real = F.fit

    def fit(*args: object, **kwargs: object) -> F.FitResult:
        if kwargs.get("stage") == stage:
            raise exc
        return real(*args, **kwargs)

    monkeypatch.setattr(F, "fit", fit)


def test_a_crash_in_stage_2_keeps_stage_1_on_disk(tmp_path: Path, virtual_csv, monkeypatch) -> None:
    data = virtual_csv(tmp_path, 19, 1)
    crash_in_stage(monkeypatch, 2, OverflowError("math range error"))
    out = tmp_path / "out" / "cell.bpx.json"
    seen: list[int] = []
    with pytest.raises(workflow.StageFailed) as info:
        workflow.fit(
            workflow.FitOptions([data], "nca18650", params="table9", max_iter=4, output=out),
            [workflow.on_stage(lambda k, r: seen.append(k))],
        )
    exc = info.value
    assert (exc.stage, exc.total, exc.kept, seen) == (2, 4, 1, [1])
    assert isinstance(exc.cause, OverflowError) and exc.written == (out, out.with_name("cell.summary.json"))
    text = str(exc)
    assert "\n" not in text and text.startswith("fit failed in stage 2 of 4: OverflowError: math range error")
    assert f"stage 1 of 4 kept (partial) in {out}" in text
    summary = json.loads(out.with_name("summary.json").read_text())
    assert summary["partial"] is True and summary["status"] == "partial: stage 1 of 4"
    assert (summary["stages_done"], summary["stages_total"], summary["converged"]) == (1, 4, False)
    assert [s["parameters"] for s in summary["stages"]] == [["R_s_n", "R_s_p"]]
    fitted = battlab.Cell.from_bpx(out)  # loadable, and it is stage 1's cell
    stage1 = exc.report.results[0]
    for name in ("R_s_n", "R_s_p"):
        assert fitted[name] == pytest.approx(stage1.cell[name], rel=1e-12)
        assert summary["parameters"][name]["value"] == pytest.approx(stage1.cell[name], rel=1e-12)
    assert "partial: stage 1 of 4" in json.loads(out.read_text())["Header"]["Description"]
    written = sorted(p.name for p in out.parent.iterdir())
    assert written == ["cell.bpx.json", "cell.summary.json", "summary.json"]  # no temporary left


def test_each_stage_is_written_as_it_finishes_and_the_last_is_complete(tmp_path: Path, virtual_csv) -> None:
    data = virtual_csv(tmp_path, 19, 1)
    out = tmp_path / "cell.bpx.json"
    status: list[tuple[str, int]] = []

    def on_stage(k: int, r: F.FitResult) -> None:  # the file on disk when stage k's callback runs
        s = json.loads(out.with_name("summary.json").read_text())
        status.append((s["status"], len(s["stages"])))
        assert battlab.Cell.from_bpx(out)["R_s_n"] == pytest.approx(r.cell["R_s_n"], rel=1e-12)

    rep = workflow.fit(
        workflow.FitOptions([data], "nca18650", params="table9", max_iter=2, output=out), [workflow.on_stage(on_stage)]
    )
    assert status == [
        ("partial: stage 1 of 4", 1),
        ("partial: stages 1–2 of 4", 2),
        ("partial: stages 1–3 of 4", 3),
        ("complete: stages 1–4 of 4", 4),
    ]
    final = json.loads(out.with_name("summary.json").read_text())
    assert final["partial"] is False and final == json.loads(json.dumps(rep.summary, default=workflow.json_default))
    assert final["converged"] == all(s["converged"] for s in final["stages"])
    assert "complete: stages 1–4 of 4" in json.loads(out.read_text())["Header"]["Description"]


def test_a_crash_in_stage_1_keeps_the_equilibrium_fit_on_disk(
    tmp_path: Path, virtual_csv, ocv_csv, monkeypatch
) -> None:
    """The equilibrium fit (C/20 test) is written, marked partial, before stage 1 starts: a crash there keeps it."""
    data = virtual_csv(tmp_path, 19, 1)
    crash_in_stage(monkeypatch, 1, RuntimeError("solver diverged"))
    out = tmp_path / "out" / "cell.bpx.json"
    seen: list[tuple[str, float]] = []

    def on_equilibrium(name: str, eq: object) -> None:  # the file on disk when the equilibrium callback runs
        s = json.loads(out.with_name("summary.json").read_text())
        seen.append((s["status"], s["parameters"]["eps_s_n"]["value"]))

    with pytest.raises(workflow.StageFailed) as info:
        workflow.fit(
            workflow.FitOptions([ocv_csv, data], "nca18650", params="table9", output=out),
            [workflow.on_equilibrium(on_equilibrium)],
        )
    exc = info.value
    eq = exc.report.equilibrium
    assert eq is not None and exc.report.equilibrium_data == "c20"
    assert (exc.stage, exc.total, exc.kept) == (1, 4, 0) and exc.written == (out, out.with_name("cell.summary.json"))
    assert seen == [("partial: equilibrium only (stages 0 of 4)", eq.eps_s_n)]
    text = str(exc)
    assert text == (
        "fit failed in stage 1 of 4: RuntimeError: solver diverged; equilibrium only (stages 0 of 4) kept (partial) "
        f"in {out} and {out.with_name('cell.summary.json')}"
    )
    summary = json.loads(out.with_name("summary.json").read_text())
    assert summary == json.loads(out.with_name("cell.summary.json").read_text())
    assert summary["partial"] is True and summary["status"] == "partial: equilibrium only (stages 0 of 4)"
    assert (summary["stages_done"], summary["stages_total"], summary["converged"], summary["stages"]) == (
        0,
        4,
        False,
        [],
    )
    assert set(summary["parameters"]) == {"eps_s_n", "eps_s_p", "n_Li"} and summary["rmse_mV"]["c20"] == eq.rmse_mV
    assert summary["equilibrium"]["eps_s_n"] == eq.eps_s_n
    fitted = battlab.Cell.from_bpx(out)  # loadable, and it is the equilibrium fit's cell
    for name in ("eps_s_n", "eps_s_p", "n_Li"):
        assert summary["parameters"][name]["value"] == pytest.approx(getattr(eq, name), rel=1e-12)
        assert fitted[name] == pytest.approx(eq.cell[name], rel=1e-12)
    assert fitted["eps_s_n"] != pytest.approx(battlab.Cell.load("nca18650")["eps_s_n"], rel=1e-6)
    assert "partial: equilibrium only (stages 0 of 4)" in json.loads(out.read_text())["Header"]["Description"]
    assert sorted(p.name for p in out.parent.iterdir()) == ["cell.bpx.json", "cell.summary.json", "summary.json"]


def test_extension_parameters_join_the_last_stage() -> None:
    cell = battlab.Cell.load("nca18650").with_extension("contact_resistance", R_c=0.002)
    table9 = workflow.stages("table9", None, [], cell=cell)
    assert table9[-1].names[-2:] == ("contact_resistance.R_c", "contact_resistance.dRc_dT")
    assert [len(s.names) for s in table9[:-1]] == [len(g) for g in battlab.parameters.TABLE9_GROUPS[:-1]]
    assert workflow.stages("all", None, [], cell=cell)[0].names == cell.parameter_names()
    assert workflow.stages("all", None, [])[0].names == battlab.parameters.NAMES


def test_an_electrodes_four_orbit_parameters_are_fitted_as_its_invariants(tmp_path: Path, virtual_csv) -> None:
    """R_s, D_s, k, R_f of one electrode: R_s is held at the start cell's value (an exact reparametrisation), the
    information matrix of the rest is regular, and the summary reports τ, κ, ρ with intervals and the four
    parameters as set-identified."""
    from battlab import Cell

    a = virtual_csv(tmp_path, 19, 3)
    names = "R_s_n,D_s_n,k_n,R_f_n"
    rep = workflow.fit(workflow.FitOptions([a], "nca18650", params=names, max_iter=3, output=tmp_path / "fit.bpx.json"))
    st = rep.last.statistics
    assert rep.last.names == ("D_s_n", "k_n", "R_f_n") and st.valid and not st.null_space
    assert rep.cell["R_s_n"] == Cell.load("nca18650")["R_s_n"]
    s = json.loads((tmp_path / "fit.summary.json").read_text())
    assert set(s["invariants"]) == {"tau_n", "kappa_n", "rho_n"}
    for inv in s["invariants"].values():
        assert inv["ci95"][0] <= inv["value"] <= inv["ci95"][1]
    assert s["held"] == {"R_s_n": pytest.approx(Cell.load("nca18650")["R_s_n"])}
    assert all(s["parameters"][n]["set_identified"] for n in names.split(","))


def test_full_charge_at_ocv_start_puts_soc_1_where_the_ocv_test_starts() -> None:
    """An OCV test that starts below V_max (the lab's full charge relaxed to its rest voltage): with "ocv-start"
    SOC 1 is that start state (its OCV and the charge to V_min match the data), with "v-max" it is not."""
    import numpy as np

    from battlab.identify.equilibrium import OcvCurve, fit_equilibrium

    cell = battlab.Cell.load("nca18650")
    cap = cell.capacity()
    q = np.linspace(0.0, 0.95 * cap, 200)  # from SOC 0.95 down to SOC 0
    curve = OcvCurve(q, np.asarray(cell.ocv(0.95 - q / cap)), "synthetic", 0.0, "start95")
    eq = fit_equilibrium(curve, cell)
    assert float(eq.cell.ocv(1.0)) == pytest.approx(4.2, abs=1e-6)  # the paper's window: SOC 1 at V_max
    full = workflow.full_charge_at_ocv_start(eq)
    assert float(full.ocv(1.0)) == pytest.approx(float(cell.ocv(0.95)), abs=2e-3)
    assert float(full.ocv(0.0)) == pytest.approx(float(eq.cell.ocv(0.0)), abs=1e-9)
    assert full.capacity() == pytest.approx(0.95 * cap, rel=5e-3)
    assert full.stoichiometry(1.0) == pytest.approx(cell.stoichiometry(0.95), abs=2e-3)


def test_full_charge_ocv_start_without_an_ocv_test_is_one_clear_error(tmp_path: Path, virtual_csv) -> None:
    from protocols.errors import InputError

    data = virtual_csv(tmp_path, 19, 1)
    with pytest.raises(InputError, match="--full-charge ocv-start needs an OCV test"):
        workflow.fit(workflow.FitOptions([data], "nca18650", params="R_s_n", full_charge="ocv-start", max_iter=1))
    with pytest.raises(InputError, match="full charge 'soc1'"):
        workflow.fit(workflow.FitOptions([data], "nca18650", params="R_s_n", full_charge="soc1", max_iter=1))
