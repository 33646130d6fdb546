"""The built-in cells nca18650 / nca18650-true and the Cell value type."""

from __future__ import annotations

import math
import os
import tomllib
from importlib import resources
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
import tomli_w
from hypothesis import given, settings
from hypothesis import strategies as st

from battlab import Cell, parameters
from battlab.cell import KEYS, F
from battlab.functions import Expr, Table
from protocols.errors import InputError

DATA = Path(os.environ.get("BATTLAB_DATA", Path(__file__).resolve().parents[3] / "shared" / "data"))
PANASONIC = DATA / "panasonic-18650pf" / "25degC_C20_OCV.mat"

#: Paper Table 5: SOC -> voltage [V]
TABLE5 = {0.8: 3.9481, 0.6: 3.7689, 0.4: 3.5982, 0.2: 3.4562}
#: OCV agreement required with Table 5 and with the real NCR18650PF C/20 discharge [V]
OCV_TOL = 0.025


@pytest.fixture(scope="module")
def cell() -> Cell:
    return Cell.load("nca18650")


@pytest.fixture(scope="module")
def truth() -> Cell:
    return Cell.load("nca18650-true")


def _toml() -> dict:
    with resources.files("battlab.cells").joinpath("nca18650.toml").open("rb") as fh:
        return tomllib.load(fh)


# --- the built-in cell ----------------------------------------------------------------------------------
def test_capacity_is_rated_within_one_percent(cell: Cell) -> None:
    assert cell.capacity() == pytest.approx(2.7, rel=0.01)
    assert float(cell["Q_nom"]) == 2.7
    # eq. 21: capacity bounded by each electrode and by the cyclable lithium
    assert cell.capacity() < min(cell.electrode_moles("n"), cell.electrode_moles("p")) * F / 3600
    assert cell.lithium_moles() == pytest.approx(0.1406)


def test_paper_nominal_and_equilibrium_values(cell: Cell) -> None:
    for p in parameters.DYNAMIC:
        assert float(cell[p.name]) == p.nominal, p.name
    for k, v in parameters.EQUILIBRIUM_TRUTH.items():
        assert float(cell[k]) == v, k
    assert (float(cell["V_min"]), float(cell["V_max"]), float(cell["T_max"])) == (2.5, 4.2, 323.15)


def test_ocv_spans_the_voltage_window_and_falls_with_discharge(cell: Cell) -> None:
    soc = np.linspace(0.0, 1.0, 4001)
    v = cell.ocv(soc)
    assert v[0] == pytest.approx(2.5, abs=1e-9) and v[-1] == pytest.approx(4.2, abs=1e-9)
    assert np.all(np.diff(v) > 0), "OCV must fall monotonically as SOC falls (discharge)"
    n0, n1, p0, p1 = cell.stoichiometry_window()
    assert 0 < n0 < n1 < 1 and 0 < p1 < p0 < 1


def test_ocv_matches_paper_table5(cell: Cell) -> None:
    """Tolerance 25 mV: the paper's Table 5 is its own fit; ours uses published OCP functions."""
    for soc, v in TABLE5.items():
        assert float(cell.ocv(soc)) == pytest.approx(v, abs=OCV_TOL), soc


def test_ocv_matches_panasonic_c20_discharge(cell: Cell) -> None:
    """Real NCR18650PF C/20 discharge (pseudo-OCV): within 25 mV at Table 5's SOCs, RMS ≤ 25 mV on 5–95 %."""
    if not PANASONIC.is_file():
        pytest.skip(f"Panasonic data not found at {PANASONIC} (set BATTLAB_DATA)")
    from scipy.io import loadmat

    m = loadmat(PANASONIC, squeeze_me=True, struct_as_record=False)["meas"]
    dis = np.flatnonzero(m.Current < -0.05)
    ah_full, ah_empty = m.Ah[dis[0] - 1], m.Ah[dis[-1]]
    soc = (m.Ah[dis] - ah_empty) / (ah_full - ah_empty)
    assert ah_full - ah_empty == pytest.approx(3.0, abs=0.05)  # the data are what we think they are
    grid = np.linspace(0.05, 0.95, 19)
    measured = np.interp(grid, soc[::-1], m.Voltage[dis][::-1])
    rms = math.sqrt(np.mean((cell.ocv(grid) - measured) ** 2))
    assert rms <= 0.025
    for s in TABLE5:
        assert float(cell.ocv(s)) == pytest.approx(np.interp(s, soc[::-1], m.Voltage[dis][::-1]), abs=0.03)


def test_every_value_has_a_source() -> None:
    data = _toml()
    params = data["parameters"]
    missing = [k for k, e in params.items() if not (isinstance(e, dict) and str(e.get("source", "")).strip())]
    assert not missing, f"values without a source: {missing}"
    adjusted = [k for k, e in params.items() if "ADJUSTED" in e["source"]]
    assert sorted(adjusted) == ["c_max_n", "c_max_p"]
    required = [k for k, spec in KEYS.items() if spec.required]
    assert set(required) <= set(params)
    cell = Cell.load("nca18650")
    assert set(cell.sources) == set(cell.values)


def test_functions_finite_and_backends_agree(cell: Cell) -> None:
    sym = ca.SX.sym("x")
    grids = {"sto": np.linspace(-0.05, 1.05, 111), "c_e": np.linspace(1.0, 6000.0, 121)}
    for key, spec in KEYS.items():
        if spec.function_of is None or key not in cell.values:
            continue
        x = grids[spec.function_of]
        ref = np.asarray(cell.fn(key, x), float)
        assert np.all(np.isfinite(ref)), key
        fun = ca.Function("f", [sym], [cell.fn(key, sym, "casadi")])
        got = np.array([float(fun(v)) for v in x])
        np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-15, err_msg=key)
    c_e = grids["c_e"]
    assert np.all(cell.fn("D_e", c_e) > 0) and np.all(cell.fn("kappa", c_e) > 0)
    assert float(cell.fn("dlnf", 1000.0)) == pytest.approx(1.132, abs=0.01)  # Valøen–Reimers at 1 M


def test_exchange_current_density_is_of_order_1e2(cell: Cell) -> None:
    """eq. A18 at SOC 0.5, c_e = c_e0, T_ref: the paper's nominal k gives i0 ~ 10² A/m² (negative)."""
    th_n, th_p = cell.stoichiometry(0.5)
    ce = float(cell["c_e0"])
    i0 = {}
    for s, th in (("n", th_n), ("p", th_p)):
        c_max = float(cell[f"c_max_{s}"])
        i0[s] = float(cell[f"k_{s}"]) * math.sqrt(th * c_max * ce * (c_max - th * c_max))
    assert 100.0 <= i0["n"] <= 1000.0
    assert 1000.0 <= i0["p"] <= 3000.0


def test_truth_differs_only_in_the_dynamic_values(cell: Cell, truth: Cell) -> None:
    assert set(truth.values) == set(cell.values)
    changed = {k for k in cell.values if to_cmp(cell[k]) != to_cmp(truth[k])}
    assert changed == {p.name for p in parameters.DYNAMIC if p.truth != p.nominal}
    for p in parameters.DYNAMIC:
        assert float(truth[p.name]) == p.truth
    assert truth.capacity() == pytest.approx(cell.capacity(), rel=1e-12)


def to_cmp(v: object) -> object:
    return v.text if isinstance(v, Expr) else v


# --- values, normalisation, errors ----------------------------------------------------------------------
def test_with_values_returns_new_cell(cell: Cell) -> None:
    new = cell.with_values(D_s_n=3e-14, U_n="0.1 + 0*x")
    assert float(new["D_s_n"]) == 3e-14 and float(cell["D_s_n"]) == 3.9e-14
    assert "D_s_n" not in new.sources and "D_s_n" in cell.sources
    assert new.hash() != cell.hash() and cell.with_values().hash() == cell.hash()
    with pytest.raises(TypeError):
        cell.values["D_s_n"] = 1.0  # type: ignore[index]


@pytest.mark.parametrize("theta", [0.0, 0.37, 1.0, -0.2, 1.3])
def test_with_normalised_round_trip(cell: Cell, theta: float) -> None:
    for p in parameters.DYNAMIC:
        value = p.denormalise(theta)
        if p.scale is parameters.Scale.LINEAR and value <= 0:
            continue  # e.g. a negative radius is not a cell
        if p.name in ("eps_e_n", "eps_e_p") and theta > 1:
            with pytest.raises(InputError, match="must be below 1"):  # no room left for the solid
                cell.with_normalised(**{p.name: theta})
            continue
        new = cell.with_normalised(**{p.name: theta})
        assert new.normalised(p.name) == pytest.approx(theta, abs=1e-12), p.name
        assert float(new[p.name]) == pytest.approx(value, rel=1e-12)


def test_nominal_values_on_a_bound_normalise_to_one(cell: Cell) -> None:
    for name in ("eps_e_s", "t_plus", "R_f_p"):
        assert cell.normalised(name) == pytest.approx(1.0)


def test_values_outside_identification_bounds_are_allowed(cell: Cell) -> None:
    new = cell.with_values(D_s_n=5e-12, k_n=1e-2, c_e0=2000.0, eps_e_n=0.4, R_f_n=0.0)
    assert new.normalised("D_s_n") > 1 and new.normalised("R_f_n") < 0


@pytest.mark.parametrize(
    ("updates", "fragment"),
    [
        ({"D_s_nn": 1e-14}, "unknown parameter"),
        ({"foo": 1.0}, "unknown parameter"),
        ({"D_s_n": -1e-14}, "must be positive"),
        ({"D_s_p": 0.0}, "must be positive"),
        ({"eps_e_n": 1.0}, "(0, 1)"),
        ({"eps_e_s": 1.2}, "(0, 1)"),
        ({"eps_e_p": 0.35, "eps_s_p": 0.7}, "must be below 1"),
        ({"t_plus": -0.1}, "must be positive"),
        ({"R_f_n": -1e-4}, "≥ 0"),
        ({"k_p": float("nan")}, "finite"),
        ({"sigma_n": "2*x"}, "must be a number"),
        ({"U_n": "x.real"}, "not allowed"),
        ({"V_min": 4.3}, "below V_max"),
    ],
)
def test_impossible_values_are_input_errors(cell: Cell, updates: dict, fragment: str) -> None:
    with pytest.raises(InputError) as err:
        cell.with_values(**updates)
    assert fragment in str(err.value) and "\n" not in str(err.value)


def test_with_normalised_unknown_name(cell: Cell) -> None:
    with pytest.raises(InputError, match="unknown parameter"):
        cell.with_normalised(L_n=0.5)


def test_adiabatic_surface_is_allowed(cell: Cell) -> None:
    assert float(cell.with_values(h2a=0.0)["h2a"]) == 0.0
    with pytest.raises(InputError):
        cell.with_values(h2a=-0.1)


_CELL = Cell.load("nca18650")


@settings(max_examples=80, deadline=None)
@given(st.floats(0.0, 1.0, allow_nan=False))
def test_soc_from_voltage_inverts_ocv(soc: float) -> None:
    cell = _CELL
    assert cell.soc_from_voltage(float(cell.ocv(soc))) == pytest.approx(soc, abs=1e-9)


@pytest.mark.parametrize("volts", [2.4, 4.3, float("nan")])
def test_soc_from_voltage_out_of_range(cell: Cell, volts: float) -> None:
    with pytest.raises(InputError):
        cell.soc_from_voltage(volts)


@pytest.mark.parametrize("soc", [-0.01, 1.01, float("nan")])
def test_stoichiometry_rejects_bad_soc(cell: Cell, soc: float) -> None:
    with pytest.raises(InputError):
        cell.stoichiometry(soc)


def test_toml_round_trip_with_a_table(tmp_path: Path, cell: Cell) -> None:
    new = cell.with_values(D_s_n_shape=Table((0.0, 0.5, 1.0), (2.0, 1.0, 0.5)))
    path = tmp_path / "cell.toml"
    path.write_text(tomli_w.dumps(new.to_toml_dict()))
    back = Cell.load(path)
    assert back.hash() == new.hash()
    assert back.sources == new.sources


@pytest.mark.parametrize("table", [{"x": 5, "y": 1}, {"x": ["a", "b"], "y": [1, 2]}])
def test_a_table_that_is_not_lists_of_numbers_names_the_file_and_parameter(
    tmp_path: Path, cell: Cell, table: dict[str, object]
) -> None:
    data = cell.to_toml_dict()
    data["parameters"]["D_e"]["value"] = table
    path = tmp_path / "cell.toml"
    path.write_text(tomli_w.dumps(data))
    with pytest.raises(InputError, match=r"cell.toml: .*D_e.*table: x and y must be lists of numbers"):
        Cell.load(path)


def test_load_errors(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="not a built-in cell"):
        Cell.load("no-such-cell")
    bad = tmp_path / "bad.toml"
    bad.write_text("name = 'x'\n[parameters]\nL_n = 1e-5\n")
    with pytest.raises(InputError, match="missing parameter"):
        Cell.load(bad)
    bad.write_text("not toml [")
    with pytest.raises(InputError, match="not valid TOML"):
        Cell.load(bad)


def test_a_cell_name_can_switch_catalog_extensions_on() -> None:
    """``CELL+KEY[:NAME=VALUE,...]``: a virtual truth that hides an effect, written where a cell name goes (the
    campaign's ``[campaign] truth``); a mistake is one error naming the part."""
    c = Cell.load("nca18650-true+contact_resistance:R_c=0.005+hysteresis:M_n=0.01,gamma_n=40")
    assert c.extensions["contact_resistance"]["R_c"] == 0.005 and c.extensions["hysteresis"]["gamma_n"] == 40.0
    assert c["D_s_n"] == Cell.load("nca18650-true")["D_s_n"]
    with pytest.raises(InputError, match="did you mean 'contact_resistance'"):
        Cell.load("nca18650+contact_resistence")
    with pytest.raises(InputError, match="'R_c=five' is not NAME=VALUE with a number"):
        Cell.load("nca18650+contact_resistance:R_c=five")
