"""BPX import/export (battlab.io.bpx) against the bpx package and PyBaMM's BPX importer."""

from __future__ import annotations

import copy
import json
import math
import os
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from battlab import Cell
from battlab.cell import KEYS, F
from battlab.functions import Expr, Table, evaluate
from battlab.io.bpx import EXT, read_bpx, write_bpx
from protocols.errors import InputError
from tests.conftest import reference

DATA = Path(os.environ.get("BATTLAB_DATA", Path(__file__).resolve().parents[4] / "shared" / "data")) / "bpx"
FILES = [
    "nmc_pouch_cell_BPX.json",
    "lfp_18650_cell_BPX.json",
    "nmc_pouch_cell_BPX_user-defined_hysteresis.json",
]
NMC = DATA / FILES[0]
HYST = DATA / FILES[2]
needs_data = pytest.mark.skipif(not NMC.is_file(), reason=f"BPX examples not found in {DATA} (set BATTLAB_DATA)")

STO = np.linspace(0.0, 1.0, 101)
CE = np.linspace(1.0, 4000.0, 101)


def assert_same_cell(a: Cell, b: Cell, rtol: float = 1e-12) -> None:
    """Same keys; numbers equal to rtol; functions equal on a grid of their variable."""
    assert set(a.values) == set(b.values)
    for key, va in a.values.items():
        vb = b.values[key]
        spec = KEYS[key]
        if spec.function_of is None:
            assert float(vb) == pytest.approx(float(va), rel=rtol, abs=0.0), key
        else:
            x = STO if spec.function_of == "sto" else CE
            np.testing.assert_allclose(evaluate(vb, x), evaluate(va, x), rtol=rtol, atol=1e-300, err_msg=key)


def _load(path: Path) -> dict[str, Any]:
    return json.loads(path.read_text())


def _write(tmp_path: Path, obj: dict[str, Any], name: str = "cell.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(obj))
    return path


# --- reading the example files --------------------------------------------------------------------------
@needs_data
def test_nmc_pouch_mapping_follows_pybamm_conventions() -> None:
    raw = _load(NMC)["Parameterisation"]
    cell = read_bpx(NMC)
    neg, pos, sep = raw["Negative electrode"], raw["Positive electrode"], raw["Separator"]
    assert float(cell["L_s"]) == sep["Thickness [m]"] and float(cell["eps_e_s"]) == sep["Porosity"]
    assert cell.name == "nmc_pouch_cell_BPX"
    assert float(cell["A"]) == pytest.approx(0.016808 * 34)
    assert float(cell["eps_s_n"]) == pytest.approx(neg["Surface area per unit volume [m-1]"] * 4.12e-6 / 3)
    assert float(cell["B_p"]) == pos["Transport efficiency"]
    assert float(cell["brugg_s"]) == pytest.approx(math.log(0.3222) / math.log(0.47))
    assert float(cell["brugg_s_n"]) == 0.0 and float(cell["sigma_n"]) == neg["Conductivity [S.m-1]"]
    k_bpx, c_max = neg["Reaction rate constant [mol.m-2.s-1]"], neg["Maximum concentration [mol.m-3]"]
    assert float(cell["k_n"]) == pytest.approx(k_bpx * F / (c_max * math.sqrt(1000.0)))
    assert cell.stoichiometry_window() == (0.005504, 0.75668, 0.9621, 0.42424)
    assert float(cell["dlnf"]) == 0.0 and float(cell["dlnf_scale"]) == 1.0
    assert float(cell["c_e0"]) == 1000.0 and float(cell["t_plus"]) == 0.2594
    assert float(cell["E_k_p"]) == 35000 and float(cell["E_D_e"]) == 17100
    hn = cell.electrode_moles("n")
    assert float(cell["n_Li"]) == pytest.approx(hn * 0.005504 + cell.electrode_moles("p") * 0.9621)
    # thermal: lumped rho c_p V in the core, adiabatic (no heat transfer coefficient in a v0.1 file)
    c_tot = 1847 * 913 * 0.000128
    assert float(cell["C1"]) + float(cell["C2"]) == pytest.approx(c_tot)
    assert float(cell["C2"]) < 1e-2 * c_tot and float(cell["h12"]) * 1.0 >= c_tot
    assert float(cell["h2a"]) == 0.0
    assert float(cell["T_max"]) == 333.15 and "333.15" in cell.sources["T_max"]
    assert all(s.startswith("BPX file nmc_pouch_cell_BPX.json") for s in cell.sources.values())
    assert set(cell.sources) == set(cell.values)


@needs_data
def test_lfp_entropic_table_is_a_sorted_table() -> None:
    cell = read_bpx(DATA / FILES[1])
    dudt = cell["dUdT_p"]
    assert isinstance(dudt, Table) and list(dudt.x) == sorted(dudt.x)
    assert isinstance(cell["U_p"], Expr)
    assert cell.capacity() == pytest.approx(2.08, rel=0.01)


@needs_data
def test_hysteresis_file_reads_the_mean_of_both_branches() -> None:
    raw = _load(HYST)["Parameterisation"]["User-defined"]
    lith, delith = (
        raw["Negative electrode lithiation OCP [V]"],
        raw["Negative electrode delithiation OCP [V]"],
    )
    cell = read_bpx(HYST)
    x = np.linspace(0.05, 0.95, 37)

    def interp(t: dict) -> np.ndarray:
        order = np.argsort(t["x"])
        return np.interp(x, np.asarray(t["x"])[order], np.asarray(t["y"])[order])

    mean = 0.5 * (interp(lith) + interp(delith))
    np.testing.assert_allclose(cell.fn("U_n", x), mean, atol=1e-12)
    assert "mean" in cell.sources["U_n"] and "hysteresis is not modelled" in cell.sources["U_n"]
    assert np.all(np.diff(cell.ocv(np.linspace(0, 1, 201))) > -1e-3)


@needs_data
@pytest.mark.parametrize("name", FILES)
def test_round_trip_of_the_example_files(tmp_path: Path, name: str) -> None:
    import bpx

    first = read_bpx(DATA / name)
    out = write_bpx(first, tmp_path / name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the nmc file's own STO limits give 4.2018 V > 4.2 V + 1 mV
        parsed = bpx.parse_bpx_file(out, convert_legacy=False)  # current schema, no migration
    assert parsed.header.bpx == bpx.__version__
    assert_same_cell(first, read_bpx(out))


# --- writing battlab cells ------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["nca18650", "nca18650-true"])
def test_round_trip_of_battlab_cells(tmp_path: Path, name: str) -> None:
    import bpx

    cell = Cell.load(name)
    out = cell.to_bpx(tmp_path / f"{name}.json")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # current schema and STO limits consistent with the cut-offs
        bpx.parse_bpx_file(out, convert_legacy=False)
    back = Cell.from_bpx(out)
    assert_same_cell(cell, back)
    assert "sto_n_0" not in back.values  # the window still follows from n_Li, as in the original
    assert all(s.startswith(f"BPX file {name}.json") for s in back.sources.values())


def test_export_contents_and_extra_metadata(tmp_path: Path) -> None:
    cell = Cell.load("nca18650-true")
    out = write_bpx(
        cell,
        tmp_path / "fit.json",
        confidence_intervals={"D_s_n": (2.4e-14, 2.8e-14), "R_s_n": [2.0e-5, 2.05e-5]},
        fit_report={"converged": True, "rmse_mV": {"US06": 12.5}, "note": "cumulative, 4 groups"},
    )
    obj = _load(out)
    par = obj["Parameterisation"]
    user = par["User-defined"]
    assert user["confidence_intervals: D_s_n [0]"] == 2.4e-14 and user["confidence_intervals: R_s_n [1]"] == 2.05e-5
    assert user["fit_report: converged"] == 1 and user["fit_report: rmse_mV: US06"] == 12.5
    assert "fit_report: note: cumulative, 4 groups" in obj["Header"]["Description"]
    assert all(not isinstance(v, str) or k.startswith(EXT) for k, v in user.items())
    neg = par["Negative electrode"]
    eps_s, r_s = float(cell["eps_s_n"]), float(cell["R_s_n"])
    assert neg["Surface area per unit volume [m-1]"] == pytest.approx(3 * eps_s / r_s)
    assert neg["Conductivity [S.m-1]"] == pytest.approx(500.0 * eps_s**1.5)  # effective sigma
    assert neg["Transport efficiency"] == pytest.approx(0.289**1.5)
    assert neg["Minimum stoichiometry"] < neg["Maximum stoichiometry"]
    assert par["Positive electrode"]["Minimum stoichiometry"] == pytest.approx(cell.stoichiometry(1.0)[1])
    # identified scale factors are multiplied into the electrolyte functions PyBaMM sees
    d_e = Expr(par["Electrolyte"]["Diffusivity [m2.s-1]"])
    assert float(d_e(1000.0)) == pytest.approx(1.195 * float(cell.fn("D_e", 1000.0)))
    assert obj["State"]["Initial conditions"]["Initial electrolyte concentration [mol.m-3]"] == 1500.0
    assert user[EXT + "C2"] == float(cell["C2"]) and user[EXT + "T_max"] == 323.15


def test_functions_pybamm_cannot_run_are_exported_as_tables(tmp_path: Path) -> None:
    cell = Cell.load("nca18650")
    u_p = str(cell["U_p"].text)
    odd = cell.with_values(U_p=f"{u_p} + 0*sqrt(x + 1)", dUdT_p="1e-5*sin(pi*x)")
    obj = _load(write_bpx(odd, tmp_path / "odd.json"))
    pos = obj["Parameterisation"]["Positive electrode"]
    assert isinstance(pos["OCP [V]"], dict) and isinstance(pos["Entropic change coefficient [V.K-1]"], dict)
    back = read_bpx(tmp_path / "odd.json")
    x = np.linspace(0.25, 0.9, 50)
    np.testing.assert_allclose(back.fn("U_p", x), odd.fn("U_p", x), atol=2e-3)  # linear table, 201 points
    const = cell.with_values(dUdT_n="1e-5*pi + 0*x")
    neg = _load(write_bpx(const, tmp_path / "c.json"))["Parameterisation"]["Negative electrode"]
    assert "pi" not in neg["Entropic change coefficient [V.K-1]"]  # inlined: BPX knows only x


def test_diffusivity_function_of_stoichiometry(tmp_path: Path) -> None:
    cell = Cell.load("nca18650")
    obj = _load(write_bpx(cell, tmp_path / "a.json"))
    obj["Parameterisation"]["User-defined"] = {}
    neg = obj["Parameterisation"]["Negative electrode"]
    neg["Diffusivity [m2.s-1]"] = "3e-14*exp(-2*x)"
    pos = obj["Parameterisation"]["Positive electrode"]
    pos["Diffusivity [m2.s-1]"] = {"x": [1.0, 0.0, 0.5], "y": [1e-14, 4e-14, 2e-14]}  # unsorted, as allowed
    back = read_bpx(_write(tmp_path, obj))
    assert float(back["D_s_n"]) == pytest.approx(3e-14 * math.exp(-1.0))
    np.testing.assert_allclose(float(back["D_s_n"]) * back.fn("D_s_n_shape", STO), 3e-14 * np.exp(-2 * STO), rtol=1e-12)
    assert float(back["D_s_p"]) == pytest.approx(2e-14)
    assert back.fn("D_s_p_shape", 0.25) == pytest.approx(1.5)
    again = read_bpx(write_bpx(back, tmp_path / "b.json"))
    assert_same_cell(back, again)


def test_heat_transfer_from_state(tmp_path: Path) -> None:
    obj = _load(write_bpx(Cell.load("nca18650"), tmp_path / "a.json"))
    obj["Parameterisation"]["User-defined"] = {}
    obj["State"]["Thermal environment"]["Heat transfer coefficient [W.m-2.K-1]"] = 10.0
    obj["Parameterisation"]["Cell"]["External surface area [m2]"] = 4.2e-3
    cell = read_bpx(_write(tmp_path, obj))
    assert float(cell["h2a"]) == pytest.approx(0.042)
    assert float(cell["C1"]) + float(cell["C2"]) == pytest.approx(Cell.load("nca18650")["C1"] + 3.1)
    assert float(cell["R_c"]) == 0.0 and float(cell["R_f_n"]) == 0.0


# --- bad input ------------------------------------------------------------------------------------------
def _nca_obj(tmp_path: Path) -> dict[str, Any]:
    return _load(write_bpx(Cell.load("nca18650"), tmp_path / "base.json"))


def _mutations() -> list[tuple[str, Any, str]]:
    def drop_area(o: dict) -> None:
        del o["Parameterisation"]["Cell"]["Electrode area [m2]"]

    def bad_ocp(o: dict) -> None:
        o["Parameterisation"]["Positive electrode"]["OCP [V]"] = "__import__('os').system('true')"

    def text_porosity(o: dict) -> None:
        o["Parameterisation"]["Separator"]["Porosity"] = "high"

    def bad_model(o: dict) -> None:
        o["Header"]["Model"] = "P2D"

    def no_version(o: dict) -> None:
        del o["Header"]["BPX"]

    def blended(o: dict) -> None:
        neg = o["Parameterisation"]["Negative electrode"]
        keep = ("Thickness [m]", "Porosity", "Transport efficiency", "Conductivity [S.m-1]")
        particle = {k: v for k, v in neg.items() if k not in keep}
        o["Parameterisation"]["Negative electrode"] = {k: neg[k] for k in keep} | {
            "Particle": {"Primary": particle, "Secondary": copy.deepcopy(particle)}
        }

    def spm(o: dict) -> None:
        o["Header"]["Model"] = "SPM"

    def porosity_one(o: dict) -> None:
        o["Parameterisation"]["Negative electrode"]["Porosity"] = 1.0

    def user_mapping(o: dict) -> None:
        o["Parameterisation"]["User-defined"]["battlab: C1"] = {"": 0.0}

    def user_call_of_text(o: dict) -> None:
        o["Parameterisation"]["User-defined"]["battlab: h12"] = "exec('import os')"

    def user_deep_nesting(o: dict) -> None:
        o["Parameterisation"]["User-defined"]["battlab: h12"] = "(" * 500 + "x" + ")" * 500

    def ocp_call_of_text(o: dict) -> None:
        o["Parameterisation"]["Negative electrode"]["OCP [V]"] = "exec('import os')"

    def user_table_decreasing(o: dict) -> None:
        o["Parameterisation"]["User-defined"]["battlab: C1"] = {"x": [2.0, 1.0], "y": [1.0, 2.0]}

    return [
        ("missing field", drop_area, "Parameterisation.Cell.Electrode area [m2]: required field is missing"),
        ("function", bad_ocp, "Parameterisation.Positive electrode.OCP [V]: not a valid BPX function of x"),
        ("type", text_porosity, "Parameterisation.Separator.Porosity"),
        ("model", bad_model, "Header.Model"),
        ("version", no_version, "BPX"),
        ("blended", blended, "blended electrodes are not supported"),
        ("spm", spm, "SPM"),
        ("porosity", porosity_one, "Porosity"),
        ("user mapping", user_mapping, "Parameterisation.User-defined.battlab: C1: expected a number"),
        ("user call", user_call_of_text, "Parameterisation.User-defined"),
        ("ocp call", ocp_call_of_text, "Negative electrode"),
        ("user nesting", user_deep_nesting, "User-defined.battlab: h12: a function nested too deeply"),
        ("user table", user_table_decreasing, "Parameterisation.User-defined.battlab: C1: table: x must increase"),
    ]


@pytest.mark.parametrize(("label", "mutate", "fragment"), _mutations(), ids=[m[0] for m in _mutations()])
def test_invalid_bpx_is_one_line_input_error(tmp_path: Path, label: str, mutate: Any, fragment: str) -> None:
    obj = _nca_obj(tmp_path)
    mutate(obj)
    path = _write(tmp_path, obj, "bad.json")
    with pytest.raises(InputError) as err:
        read_bpx(path)
    msg = str(err.value)
    assert "\n" not in msg and str(path) in msg and fragment in msg, msg


def test_not_json_and_missing_file(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text('{"Header": ')
    with pytest.raises(InputError, match="not valid JSON"):
        read_bpx(bad)
    with pytest.raises(InputError, match="not found"):
        read_bpx(tmp_path / "nothing.json")
    bad.write_text("[1, 2]")
    with pytest.raises(InputError, match="expected a BPX JSON object"):
        Cell.load(bad)


def test_unexportable_metadata(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="extra metadata"):
        write_bpx(Cell.load("nca18650"), tmp_path / "x.json", report=object())


# --- PyBaMM, the reference importer ---------------------------------------------------------------------
@needs_data
@pytest.mark.parametrize("soc", [0.2, 0.5, 0.9])
def test_stoichiometries_match_pybamm_create_from_bpx(soc: float) -> None:
    pybamm = reference("pybamm")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        param = pybamm.ParameterValues.create_from_bpx(NMC, target_soc=soc)
    sto_n = param["Initial concentration in negative electrode [mol.m-3]"] / float(
        param["Maximum concentration in negative electrode [mol.m-3]"]
    )
    sto_p = param["Initial concentration in positive electrode [mol.m-3]"] / float(
        param["Maximum concentration in positive electrode [mol.m-3]"]
    )
    ours = read_bpx(NMC).stoichiometry(soc)
    assert ours[0] == pytest.approx(sto_n, abs=1e-6)
    assert ours[1] == pytest.approx(sto_p, abs=1e-6)


def test_pybamm_reads_our_export_as_the_same_cell(tmp_path: Path) -> None:
    """Exchange current, OCP, diffusivities, conductivity, eps_s and the lumped thermal products agree."""
    pybamm = reference("pybamm")
    cell = Cell.load("nca18650-true")
    path = write_bpx(cell, tmp_path / "true.json")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        p = pybamm.ParameterValues.create_from_bpx(path)

    def val(x: Any) -> float:
        return float(x.evaluate()) if hasattr(x, "evaluate") else float(x)

    T = 310.0
    for s, name in (("n", "negative"), ("p", "positive")):
        c_max = float(cell[f"c_max_{s}"])
        c_s, c_e = 0.45 * c_max, 1200.0
        arr = math.exp(float(cell[f"E_k_{s}"]) / 8.314462618 * (1 / 298.15 - 1 / T))
        ours = float(cell[f"k_{s}"]) * arr * math.sqrt(c_e * c_s * (c_max - c_s))
        j0 = val(p[f"{name.capitalize()} electrode exchange-current density [A.m-2]"](c_e, c_s, c_max, T))
        assert j0 == pytest.approx(ours, rel=1e-9)
        assert val(p[f"{name.capitalize()} electrode OCP [V]"](0.4)) == pytest.approx(
            float(cell.fn(f"U_{s}", 0.4)), rel=1e-12
        )
        assert p[f"{name.capitalize()} electrode active material volume fraction"] == pytest.approx(
            float(cell[f"eps_s_{s}"]), rel=1e-12
        )
        d = val(p[f"{name.capitalize()} particle diffusivity [m2.s-1]"](0.4, 298.15))
        assert d == pytest.approx(float(cell[f"D_s_{s}"]), rel=1e-12)
    d_e = val(p["Electrolyte diffusivity [m2.s-1]"](1000.0, 298.15))
    assert d_e == pytest.approx(float(cell["D_e_scale"]) * float(cell.fn("D_e", 1000.0)), rel=1e-12)
    kappa = val(p["Electrolyte conductivity [S.m-1]"](1000.0, 298.15))
    assert kappa == pytest.approx(float(cell["kappa_scale"]) * float(cell.fn("kappa", 1000.0)), rel=1e-12)
    rho_cp_v = (
        p["Negative electrode density [kg.m-3]"]
        * p["Negative electrode specific heat capacity [J.kg-1.K-1]"]
        * p["Cell volume [m3]"]
    )
    assert rho_cp_v == pytest.approx(float(cell["C1"]) + float(cell["C2"]), rel=1e-12)
    h_a = p["Total heat transfer coefficient [W.m-2.K-1]"] * p["Cell cooling surface area [m2]"]
    assert h_a == pytest.approx(float(cell["h2a"]), rel=1e-12)
    assert p["Initial concentration in electrolyte [mol.m-3]"] == float(cell["c_e0"])
    th_n, th_p = cell.stoichiometry(1.0)  # PyBaMM's default initial state is 100 % SOC
    assert p["Initial concentration in negative electrode [mol.m-3]"] == pytest.approx(
        th_n * float(cell["c_max_n"]), rel=1e-12
    )
    assert p["Initial concentration in positive electrode [mol.m-3]"] == pytest.approx(
        th_p * float(cell["c_max_p"]), rel=1e-12
    )
