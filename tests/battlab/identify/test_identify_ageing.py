"""Per-file ageing: each data file's own cyclable lithium and capacity, fitted with the shared parameters."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

import battlab
from battlab.cell import rest_stoichiometries
from battlab.cli import main
from battlab.identify import ageing as A
from battlab.identify import fit as F
from battlab.identify.experiments import Experiment
from battlab.identify.forward import ForwardModel
from battlab.io.bdf import write_bdf_csv
from battlab.io.data import AMBIENT, CURRENT, TIME, VOLTAGE, LoggedData
from protocols.errors import InputError
from protocols.profile import Profile

NOISE = 1e-3  # [V]


@pytest.fixture(scope="module")
def two_dates():
    """One cell (D_s_p moved from the start cell's) tested on two "dates": file A with 6 % of its lithium and 5 % of
    its capacity lost, file B with 10 % and 3 %; a 1C discharge with 2C pulses from full charge, then a rest."""
    cell = battlab.Cell.load("nca18650")
    fm = ForwardModel(cell, v_margin=0.15)
    q = float(cell["Q_nom"])
    t = np.arange(0.0, 2600.0, 10.0)
    current = np.where(t % 300 < 30, -2 * q, -q)
    current[t > 2300] = 0.0
    prof = Profile(t, current, id="dis")
    n_ref = cell.lithium_moles()
    truth = {"A": (0.94 * n_ref, 0.95), "B": (0.90 * n_ref, 0.97)}
    theta = cell.with_values(D_s_p=3e-14).theta_bar()
    clean = {}
    for f, (n, c) in truth.items():
        start = rest_stoichiometries(cell, n, float(cell.ocv(1.0)), capacity=c)
        out = fm.run(theta, prof, 1.0, start=start, capacity=c)
        assert out.ended_by is None
        clean[f] = out.voltage
    return cell, fm, prof, truth, clean


def experiments(prof: Profile, clean: dict[str, np.ndarray]) -> list[Experiment]:
    rng = np.random.default_rng(3)
    return [Experiment(f, prof, v + rng.normal(0.0, NOISE, v.size), 1.0, NOISE**2) for f, v in clean.items()]


def test_each_files_lithium_and_capacity_are_recovered_where_one_set_cannot(two_dates) -> None:
    cell, fm, prof, truth, clean = two_dates
    exps = experiments(prof, clean)
    one = F.fit(cell, exps, ["D_s_p"], forward=fm)
    assert min(one.rmse_mV.values()) > 5 * 1e3 * NOISE  # one lithium inventory and capacity cannot fit both files
    age = A.Ageing(("n_Li", "capacity"), {"A": "A", "B": "B"}, cell.lithium_moles())
    res = F.fit(cell, exps, ["D_s_p"], forward=fm, ageing=age)
    assert res.convergence.converged, res.convergence.reason
    assert max(res.rmse_mV.values()) < 1.2e3 * NOISE
    assert res.statistics.estimates[0].covers(3e-14)
    for f, (n, c) in truth.items():
        got = res.extra["ageing"][f]
        for name, value in (("n_Li", n), ("capacity", c)):
            lo, hi = got[name]["ci95"]
            assert lo <= value <= hi, (f, name, got[name], value)
            assert got[name]["at_bound"] is None
    assert res.report()["estimates"]["D_s_p"]["ci95"] is not None
    assert res.cell["D_s_p"] == pytest.approx(res.statistics.estimates[0].value)  # the cell keeps the start's ageing
    assert res.cell.stoichiometry(1.0) == cell.stoichiometry(1.0)


def test_the_aged_cell_starts_where_the_file_started() -> None:
    cell = battlab.Cell.load("nca18650")
    n, c = 0.85 * cell.lithium_moles(), 0.9
    aged = A.aged_cell(cell, n, c, "test")
    assert aged["A"] == pytest.approx(c * cell["A"])
    np.testing.assert_allclose(
        aged.stoichiometry(1.0), rest_stoichiometries(cell, n, float(cell.ocv(1.0)), capacity=c), atol=1e-10
    )
    assert float(aged.ocv(0.0)) == pytest.approx(float(cell.ocv(0.0)), abs=1e-9)
    assert aged.lithium_moles() == pytest.approx(n, rel=1e-9)
    assert aged.capacity() < c * cell.capacity()  # lithium lost beyond the lost material's share
    assert aged.sources["A"] == "test"


def test_an_aged_cell_whose_voltage_limits_are_out_of_reach_ends_where_an_electrode_fills_or_empties() -> None:
    cell = battlab.Cell.load("nca18650")
    n, c = cell.lithium_moles(), 0.85  # more lithium than the smaller electrodes take between 2.5 and 4.2 V
    with pytest.raises(InputError, match="does not reach"):
        rest_stoichiometries(cell, n, float(cell.ocv(0.0)), capacity=c)
    aged = A.aged_cell(cell, n, c, "test")
    n0, n1, p0, p1 = aged.stoichiometry_window()
    assert max(p0, n1) == pytest.approx(1.0, abs=1e-5)  # the positive full at SOC 0 or the negative at SOC 1
    assert float(cell["V_min"]) < float(aged.ocv(0.0)) < float(aged.ocv(1.0)) <= float(cell["V_max"])
    assert aged.lithium_moles() == pytest.approx(n, rel=1e-9)


@pytest.mark.slow
def test_the_forward_model_of_a_file_matches_the_aged_cell() -> None:
    """The area factor as the current I/c with the contact drop corrected: the same voltage as the cell whose area
    is c A (isothermal: the heat of the scaled run is not the aged cell's). Compiles a model (10-30 s)."""
    cell = battlab.Cell.load("nca18650")
    n, c = 0.96 * cell.lithium_moles(), 0.9
    aged = A.aged_cell(cell, n, c, "test")
    q = float(cell["Q_nom"])
    t = np.arange(0.0, 1200.0, 5.0)
    prof = Profile(t, np.where(t % 200 < 20, -2 * q, -q))
    fm = ForwardModel(cell, isothermal=True)
    out = fm.run(
        cell.theta_bar(), prof, 1.0, start=rest_stoichiometries(cell, n, float(cell.ocv(1.0)), capacity=c), capacity=c
    )
    ref = ForwardModel(aged, isothermal=True).run(aged.theta_bar(), prof, 1.0)
    np.testing.assert_allclose(out.voltage, ref.voltage, atol=1e-6)


def _csv(tmp_path, name: str, prof: Profile, v: np.ndarray) -> str:
    cols = {TIME: prof.t, VOLTAGE: v, CURRENT: prof.current, AMBIENT: np.full(prof.t.size, 25.0)}
    return str(write_bdf_csv(LoggedData(name, cols, {"soc0": 1.0}), tmp_path / f"{name}.bdf.csv"))


def test_cli_reports_each_file_and_writes_the_mean(tmp_path, two_dates) -> None:
    cell, _, prof, truth, clean = two_dates
    exps = experiments(prof, clean)
    files = [_csv(tmp_path, e.name, prof, e.voltage) for e in exps]
    out = tmp_path / "c.bpx.json"
    args = ["fit", *files, "--cell", "nca18650", "--params", "D_s_p", "--soc0", "1", "--dt", "10", "-o", str(out)]
    r = CliRunner().invoke(main, [*args, "--per-file-ageing", "n_Li,capacity"])
    assert r.exit_code == 0, r.output
    block = json.loads((tmp_path / "c.summary.json").read_text())["per_file_ageing"]
    assert set(block["files"]) == {"A", "B"} and "ageing of A: n_Li" in r.output
    for f, (n, c) in truth.items():
        for name, value in (("n_Li", n), ("capacity", c)):
            lo, hi = block["files"][f][name]["ci95"]
            assert lo <= value <= hi
    mean = {k: np.mean([block["files"][f][k]["value"] for f in "AB"]) for k in ("n_Li", "capacity")}
    written = battlab.Cell.from_bpx(out)
    assert written.lithium_moles() == pytest.approx(mean["n_Li"], rel=1e-6)
    assert written["A"] == pytest.approx(mean["capacity"] * cell["A"], rel=1e-9)
    assert block["exported"]["n_Li"] == pytest.approx(mean["n_Li"])


@pytest.mark.parametrize(
    ("names", "n_files", "message"),
    [
        ("n_Li,foo", 2, "unknown name 'foo'"),
        ("n_Li", 1, "two or more data files"),
        ("n_Li,n_Li", 2, "given twice"),
    ],
)
def test_bad_per_file_ageing_is_one_line(tmp_path, names: str, n_files: int, message: str) -> None:
    files = [str(tmp_path / f"x{k}.bdf.csv") for k in range(n_files)]
    args = ["fit", *files, "--cell", "nca18650", "--per-file-ageing", names, "-o", str(tmp_path / "c.bpx.json")]
    r = CliRunner().invoke(main, args)
    assert r.exit_code == 2 and message in r.output and "Traceback" not in r.output
    assert len(r.output.strip().splitlines()) == 1
    with pytest.raises(InputError, match="expected some of n_Li, capacity"):
        A.parse_names("")


def test_a_capacity_ratio_between_two_dates_is_found_from_rest_points() -> None:
    """Rest voltages of a cell with 2 % more capacity (and 6 mV of hysteresis below) map onto the later curve."""
    q_b = np.linspace(0.0, 2.8, 400)
    v_b = 4.18 - 0.35 * q_b - 0.05 * np.sin(2.0 * q_b) - 0.2 * np.exp(4.0 * (q_b - 2.8))
    q_a = np.linspace(0.1, 2.5, 40)
    v_a = np.interp(q_a / 1.02, q_b, v_b) - 0.006
    r = A.capacity_ratio(q_a, v_a, q_b, v_b)
    assert r.ratio == pytest.approx(1 / 1.02, abs=2e-4)
    assert r.offset_V == pytest.approx(0.006, abs=2e-4)
    fade = A.fade_from("2017-03-11", "2017-05-08", r)
    assert fade.capacity("2017-03-11") == pytest.approx(1.02, abs=3e-4)
    assert fade.capacity("2017-05-08") == 1.0
    assert fade.capacity("2017-06-05") < 1.0  # a later date the comparison did not see: less capacity


def test_rest_points_are_the_ends_of_long_rests_at_the_logged_charge() -> None:
    t = np.arange(0.0, 8000.0)
    i = np.where((t % 4000) < 1000, -1.0, 0.0)  # 1000 s at 1 A, then 3000 s rest, twice
    v = 3.8 - 0.1 * (t > 1000)
    q, vr = A.rest_points(t, i, v)
    assert q.size == 1 and q[0] == pytest.approx(1000 / 3600, rel=1e-3)  # the last rest is not followed by current
    q2, _ = A.rest_points(t, i, v, discharged=np.full(t.size, 0.5) + 0.1 * (t > 3000))
    assert q2[0] == pytest.approx(0.1)


def test_a_cell_on_another_date_keeps_its_ocv_against_soc() -> None:
    cell = battlab.Cell.load("nca18650")
    fade = A.LinearFade("2017-05-08", 3e-4, 1e-5)
    older = A.cell_on(cell, fade, "2017-03-20")
    assert older.capacity() == pytest.approx(cell.capacity() * fade.capacity("2017-03-20"), rel=2e-3)
    for soc in (0.1, 0.5, 0.9):
        assert float(older.ocv(soc)) == pytest.approx(float(cell.ocv(soc)), abs=1e-4)
