"""BPX (Battery Parameter eXchange) import and export, following PyBaMM's BPX importer.

The mapping is that of ``pybamm/parameters/bpx.py`` (PyBaMM 26), so that a BPX cell simulated in battlab
and in PyBaMM is the same cell and starts from the same concentrations at the same SOC:

- electrolyte transport: BPX gives a transport efficiency B = ε^b per region; it becomes ``B_n``, ``B_s``,
  ``B_p`` (used instead of Bruggeman) and the equivalent exponent ``brugg_* = ln B / ln ε``, as PyBaMM does;
- electrode conductivities are effective values: ``sigma_*`` as given, ``brugg_s_* = 0``;
- area: ``A`` = electrode area × number of electrode pairs;
- active material: ε_s = a_s R_s / 3 from "Surface area per unit volume" (PyBaMM's "BET" line), so that
  a_s = 3 ε_s / R_s holds in the model;
- kinetics: BPX's j0 = F k_BPX √((c_e/c_e0)(c_s/c_max)(1 − c_s/c_max)) [mol m⁻² s⁻¹ → A m⁻²] equals
  battlab's (and PyBaMM's) j0 = k √(c_e c_s (c_max − c_s)) with k = k_BPX F / (c_max √c_e0), c_e0 the
  initial electrolyte concentration of the BPX ``State`` (1000 mol m⁻³ when absent, PyBaMM's default);
- thermodynamic factor 1 (``dlnf = 0``, ``dlnf_scale = 1``); no film or contact resistance (0);
- diffusivities given as functions of stoichiometry: ``D_s_*`` = D(θ = 0.5) and ``D_s_*_shape`` =
  D(θ)/D(0.5) (an expression or a scaled table); tables ``{"x", "y"}`` become :class:`Table`;
- SOC: ``sto_n_0``/``sto_n_100`` = negative minimum/maximum stoichiometry, ``sto_p_0``/``sto_p_100`` =
  positive maximum/minimum (PyBaMM's ``get_electrode_stoichiometries``); ``n_Li`` = H⁻θ⁻(0 %) + H⁺θ⁺(0 %);
- thermal: PyBaMM's lumped model is ρ c_p V dT/dt = Q − h A_ext (T − T_amb) with h from
  ``State.Thermal environment`` (0, adiabatic, when absent). battlab's two-state model (B1, B2) reproduces
  it with all heat capacity in the core and a stiff core-to-surface link: C1 + C2 = ρ c_p V with
  C2 = 10⁻³ ρ c_p V, h12 = ρ c_p V / (1 s) (core–surface relaxation C2/h12 = 1 ms; in steady cooling the
  core–surface difference is h2a/h12 of the rise over ambient), h2a = h A_ext. T_core is then PyBaMM's
  volume-averaged temperature (PyBaMM's lumped "surface temperature" is the ambient);
- ``T_max`` is not part of BPX: 333.15 K unless given, and the source says so.

Hysteresis: BPX cells with two OCP branches (BPX 1.x ``OCP (lithiation)``/``OCP (delithiation)`` or the
``User-defined`` "<Negative|Positive> electrode lithiation/delithiation OCP [V]" of the example file)
whose main OCP is a constant placeholder are read with the mean of the two branches (battlab does not
model hysteresis); a real main OCP is used as given, as PyBaMM does without a hysteresis option.

Export writes the current BPX schema of the installed ``bpx`` package (validated before writing) with the
same conventions in reverse (identified scale factors multiplied into D_e and κ, σ written as effective
σ ε_s^brugg_s, k converted back, the lumped-thermal equivalent ρ c_p V = C1 + C2 and h A_ext = h2a over a
nominal V = electrode-stack volume, c_p = 1000 J kg⁻¹ K⁻¹, A_ext = 6 V^(2/3)). Everything BPX cannot
hold (the two-state thermal values, T_max, R_c, R_f, the activity function, the scale factors, Bruggeman
exponents) is kept under ``User-defined`` as "battlab: <key>" entries, which :func:`read_bpx` restores,
so that battlab → BPX → battlab is exact; they take precedence over the standard fields, so remove them
when editing those fields of a battlab-written file by hand. Extra metadata (confidence intervals, a fit
report) goes under ``User-defined`` too, flattened to numbers; texts go to the header's Description.
"""

from __future__ import annotations

import ast
import json
import math
import re
import warnings
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from battlab.cell import Cell, F
from battlab.functions import Expr, Function, Table, as_function, evaluate, to_json
from protocols.errors import InputError

#: Prefix of battlab's own entries in the BPX "User-defined" section.
EXT = "battlab: "
#: Marker entry: present in every file battlab writes.
EXT_VERSION = EXT + "extension version"
#: Marker entry: 1 when the cell's stoichiometry window follows from n_Li and the voltage limits.
EXT_WINDOW = EXT + "stoichiometry window from n_Li"
#: Functions PyBaMM's BPX reader can execute (its preamble imports exp, tanh, cosh only).
PYBAMM_FUNCTIONS = frozenset({"exp", "tanh", "cosh"})
#: Heat capacity fraction kept in the surface node, and core-surface relaxation time [s].
SURFACE_FRACTION = 1e-3
CORE_SURFACE_TAU = 1.0
T_MAX_DEFAULT = 333.15  # K, when a BPX file gives none
C_E0_DEFAULT = 1000.0  # mol/m3, PyBaMM's default initial electrolyte concentration
T_REF_DEFAULT = 298.15  # K
CP_NOMINAL = 1000.0  # J/(kg K), nominal split of rho*c_p on export
RHO_CP_DEFAULT = 2.0e6  # J/(m3 K) over the electrode stack, when a BPX file has no thermal data

_CONSTANTS = {"pi": math.pi, "e": math.e}  # the named constants battlab expressions may use
_STO_GRID = np.linspace(0.0, 1.0, 201)
_CE_GRID = np.linspace(0.0, 6000.0, 241)
# keys whose value BPX cannot hold exactly: written as "battlab: <key>" and restored on reading
_EXT_KEYS = (
    *("C1", "C2", "h12", "h2a", "T_max", "R_c", "R_f_n", "R_f_p", "n_Li", "k_n", "k_p"),
    *("dlnf", "dlnf_scale", "D_e", "D_e_scale", "kappa", "kappa_scale", "sigma_n", "sigma_p"),
    *("brugg_s_n", "brugg_s_p", "brugg_n", "brugg_s", "brugg_p", "B_n", "B_s", "B_p"),
    *("D_s_n", "D_s_p", "D_s_n_shape", "D_s_p_shape"),
)


# --- reading ---------------------------------------------------------------------------------------------
def read_bpx(path: str | Path) -> Cell:
    """Read and validate a BPX JSON file (``bpx`` package; v0.x files are migrated) into a :class:`Cell`."""
    path = Path(path)
    raw = _load_json(path)
    model = _validate(raw, str(path))
    par = model.parameterisation
    for section in ("cell", "electrolyte", "negative_electrode", "positive_electrode", "separator"):
        if getattr(par, section, None) is None:
            raise InputError(
                f"{path}: BPX model {model.header.model!r} lacks the {section.replace('_', ' ')} section a DFN needs"
            )
    for label, el in (
        ("Negative electrode", par.negative_electrode),
        ("Positive electrode", par.positive_electrode),
    ):
        if hasattr(el, "particle"):
            raise InputError(
                f"{path}: BPX field Parameterisation.{label}.Particle: blended electrodes are not "
                "supported (expected a single active material)"
            )
        if not hasattr(el, "conductivity"):
            raise InputError(
                f"{path}: BPX field Parameterisation.{label}: SPM-type electrode without "
                "conductivity/porosity; a DFN parameterisation is expected"
            )

    src = f"BPX file {path.name}"
    user = _user_defined(par)
    state = model.state
    ic = state.initial_conditions if state is not None else None
    te = state.thermal_environment if state is not None else None
    c_e0 = _first(ic.initial_electrolyte_concentration if ic else None, C_E0_DEFAULT)
    values: dict[str, Any] = {}
    sources: dict[str, str] = {}

    def put(key: str, value: Any, note: str = "") -> None:
        values[key] = value
        sources[key] = src + (f" ({note})" if note else "")

    cell = par.cell
    put(
        "A",
        float(cell.electrode_area) * int(cell.number_of_electrodes),
        f"electrode area x {cell.number_of_electrodes} electrode pairs",
    )
    put("V_min", float(cell.lower_voltage_cutoff))
    put("V_max", float(cell.upper_voltage_cutoff))
    put("Q_nom", float(cell.nominal_cell_capacity))
    t_ref = cell.reference_temperature
    put("T_ref", float(_first(t_ref, T_REF_DEFAULT)), "" if t_ref is not None else "absent: 298.15 K")
    put(
        "c_e0",
        float(c_e0),
        "State initial electrolyte concentration"
        if ic and ic.initial_electrolyte_concentration is not None
        else "absent: 1000 mol/m3, PyBaMM's default",
    )

    el = par.electrolyte
    put("t_plus", float(el.cation_transference_number))
    put(
        "D_e",
        _function(el.diffusivity, f"{path}: BPX field Parameterisation.Electrolyte.Diffusivity [m2.s-1]"),
    )
    put(
        "kappa",
        _function(el.conductivity, f"{path}: BPX field Parameterisation.Electrolyte.Conductivity [S.m-1]"),
    )
    put("E_D_e", float(_first(el.diffusivity_activation_energy, 0.0)))
    put("E_kappa", float(_first(el.conductivity_activation_energy, 0.0)))
    for key in ("D_e_scale", "kappa_scale", "dlnf_scale"):
        put(key, 1.0, "BPX has no scale factors")
    put("dlnf", 0.0, "thermodynamic factor 1, as PyBaMM's BPX reader")

    sep = par.separator
    put("L_s", float(sep.thickness))
    put("eps_e_s", float(sep.porosity))
    _transport(
        put,
        "s",
        float(sep.porosity),
        float(sep.transport_efficiency),
        f"{path}: BPX field Parameterisation.Separator",
    )

    for s, e, label in (("n", par.negative_electrode, "Negative"), ("p", par.positive_electrode, "Positive")):
        where = f"{path}: BPX field Parameterisation.{label} electrode"
        put(f"L_{s}", float(e.thickness))
        put(f"eps_e_{s}", float(e.porosity))
        _transport(put, s, float(e.porosity), float(e.transport_efficiency), where)
        put(f"sigma_{s}", float(e.conductivity), "effective conductivity")
        put(f"brugg_s_{s}", 0.0, "conductivity given as effective")
        r = float(e.particle_radius)
        put(f"R_s_{s}", r)
        put(f"eps_s_{s}", float(e.surface_area_per_unit_volume) * r / 3.0, "surface area per volume x R / 3")
        c_max = float(e.maximum_concentration)
        put(f"c_max_{s}", c_max)
        d_ref, shape = _diffusivity(
            _function(e.diffusivity, where + ".Diffusivity [m2.s-1]"), where + ".Diffusivity [m2.s-1]"
        )
        put(f"D_s_{s}", d_ref, "value at stoichiometry 0.5" if shape is not None else "")
        if shape is not None:
            put(f"D_s_{s}_shape", shape, "diffusivity / its value at stoichiometry 0.5")
        put(
            f"k_{s}",
            float(e.reaction_rate_constant) * F / (c_max * math.sqrt(c_e0)),
            "k_BPX F / (c_max sqrt(c_e0)), as PyBaMM",
        )
        put(f"E_D_s_{s}", float(_first(e.diffusivity_activation_energy, 0.0)))
        put(f"E_k_{s}", float(_first(e.reaction_rate_constant_activation_energy, 0.0)))
        ocp, note = _ocp(e, user, label, where)
        put(f"U_{s}", ocp, note)
        put(
            f"dUdT_{s}",
            _function(e.dudt, where + ".Entropic change coefficient [V.K-1]") if e.dudt is not None else 0.0,
            "" if e.dudt is not None else "absent: 0",
        )
        put(f"R_f_{s}", 0.0, "BPX has no film resistance")
        lo, hi = float(e.minimum_stoichiometry), float(e.maximum_stoichiometry)
        if s == "n":
            put("sto_n_0", lo, "minimum stoichiometry")
            put("sto_n_100", hi, "maximum stoichiometry")
        else:
            put("sto_p_0", hi, "maximum stoichiometry")
            put("sto_p_100", lo, "minimum stoichiometry")
    hn = values["eps_s_n"] * values["L_n"] * values["A"] * values["c_max_n"]
    hp = values["eps_s_p"] * values["L_p"] * values["A"] * values["c_max_p"]
    put("n_Li", hn * values["sto_n_0"] + hp * values["sto_p_0"], "derived: H- sto_n_0 + H+ sto_p_0")

    # thermal: PyBaMM's lumped model as a stiff two-state model
    h = _first(te.heat_transfer_coefficient if te else None, 0.0)
    if cell.density is not None and cell.specific_heat_capacity is not None and cell.volume is not None:
        c_tot = float(cell.density) * float(cell.specific_heat_capacity) * float(cell.volume)
        note = "lumped rho c_p V"
    else:
        c_tot = RHO_CP_DEFAULT * values["A"] * (values["L_n"] + values["L_s"] + values["L_p"])
        note = "no thermal data: 2 MJ/(m3 K) over the electrode stack"
    put("C1", (1.0 - SURFACE_FRACTION) * c_tot, note + ", all but 0.1 % in the core")
    put("C2", SURFACE_FRACTION * c_tot, note + ", 0.1 % in the surface node")
    put("h12", c_tot / CORE_SURFACE_TAU, "stiff core-surface link: rho c_p V / 1 s")
    if h and cell.external_surface_area is None:
        raise InputError(
            f"{path}: BPX field Parameterisation.Cell.External surface area [m2]: required when a "
            "heat transfer coefficient is given"
        )
    a_ext = float(cell.external_surface_area) if cell.external_surface_area is not None else 0.0
    put(
        "h2a",
        float(h) * a_ext,
        "h x external surface area" if h else "no heat transfer coefficient: adiabatic, as PyBaMM's BPX reader",
    )
    put("R_c", 0.0, "BPX has no contact resistance")
    put("T_max", T_MAX_DEFAULT, "BPX has no maximum temperature: default 333.15 K")

    # battlab's own entries restore what BPX could not hold
    if EXT_VERSION in user:
        for key in ("B_n", "B_s", "B_p"):
            values.pop(key, None)
        if user.get(EXT_WINDOW) == 1 and EXT + "n_Li" in user:
            for key in ("sto_n_0", "sto_n_100", "sto_p_0", "sto_p_100"):
                values.pop(key, None)
        for key in _EXT_KEYS:
            if EXT + key in user:
                values[key] = as_function(_user_value(user[EXT + key]))
                sources[key] = src + " (battlab extension)"
    header = model.header
    desc = " ".join(t for t in (header.title, header.description) if t)
    try:
        return Cell(path.stem, values, sources, desc)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None


def _load_json(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise InputError(f"{path}: BPX file not found")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: not valid JSON ({exc.msg} at line {exc.lineno} column {exc.colno})") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a UTF-8 text file (expected BPX JSON)") from None
    if not isinstance(data, dict):
        raise InputError(f"{path}: expected a BPX JSON object with Header and Parameterisation")
    return data


_SECTIONS = {"Cell", "Electrolyte", "Negative electrode", "Positive electrode", "Separator", "User-defined"}
_HEADER = {"Model", "BPX", "Title", "Description", "References"}
_TYPE_TAG = re.compile(r"^(float|int|str|bool|none|list\[.*\]|dict\[.*\]|InterpolatedTable|function-.*|json-.*)$")


def _validate(raw: dict[str, Any], where: str) -> Any:
    """Validate with the ``bpx`` package; any failure becomes one line naming the field."""
    import bpx
    from pydantic import ValidationError

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # legacy-migration notes, float version, STO-limit checks
        try:
            return bpx.parse_bpx_obj(raw)
        except ValidationError as exc:
            raise InputError(f"{where}: {_describe(exc)}") from None
        except (ValueError, TypeError, KeyError, AttributeError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise InputError(f"{where}: invalid BPX ({first})") from None


def _describe(exc: Any) -> str:
    """One line from a pydantic ValidationError: the field path and what was expected."""
    errors = exc.errors()
    first = errors[0]

    def path_of(e: Mapping[str, Any]) -> list[str]:
        return [str(p) for p in e["loc"] if not _TYPE_TAG.match(str(p))]

    field = path_of(first)
    same = [e for e in errors if path_of(e) == field]
    tags = {str(p) for e in same for p in e["loc"] if _TYPE_TAG.match(str(p))}
    specific = [e for e in same if e["type"] == "value_error"]
    if specific:
        msg = specific[0]["msg"].removeprefix("Value error, ")
        if msg.startswith("Invalid Function"):
            where = re.search(r"\(at char (\d+)\)", msg)
            at = f" at character {int(where.group(1)) + 1}" if where else ""
            msg = f"not a valid BPX function of x{at} (numbers, x, + - * / ** and calls such as exp(), tanh())"
    elif first["type"] == "missing":
        msg = "required field is missing"
    elif any(t.startswith(("function", "InterpolatedTable")) for t in tags):
        msg = "expected a number, a function of x (string) or a {'x': [...], 'y': [...]} table"
    elif tags and tags <= {"float", "int"}:
        msg = f"expected a number, got {first.get('input')!r}"
    else:
        msg = first["msg"]
    if field and field[0] in _SECTIONS:
        field.insert(0, "Parameterisation")
    elif getattr(exc, "title", "") == "Header" or (field and field[0] in _HEADER):
        field.insert(0, "Header")
    more = len(errors) - len(same)
    tail = f" (and {more} more problem{'s' if more > 1 else ''})" if more > 0 else ""
    if not field:
        return f"invalid BPX: {msg.splitlines()[0]}{tail}"
    return f"BPX field {'.'.join(field)}: {msg.splitlines()[0]}{tail}"


def _first(value: Any, default: Any) -> Any:
    return default if value is None else value


def _function(value: Any, where: str) -> float | Function:
    """A BPX FloatFunctionTable as a number, an :class:`Expr` or a sorted :class:`Table`."""
    if value is None:
        raise InputError(f"{where}: missing")
    if isinstance(value, int | float) and not isinstance(value, bool):
        return float(value)
    if isinstance(value, str):
        try:
            return Expr(str(value))
        except InputError as exc:
            raise InputError(f"{where}: {exc}") from None
    x = np.asarray(getattr(value, "x", None), float)
    y = np.asarray(getattr(value, "y", None), float)
    order = np.argsort(x, kind="stable")  # PyBaMM sorts tables by x
    try:
        return Table(tuple(x[order]), tuple(y[order]))
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None


def _transport(put: Any, s: str, porosity: float, efficiency: float, where: str) -> None:
    if not 0.0 < porosity < 1.0 or not 0.0 < efficiency < 1.0:
        raise InputError(
            f"{where}.Porosity, Transport efficiency: {porosity:g}, {efficiency:g}: both must be in (0, 1)"
        )
    put(f"B_{s}", efficiency, "transport efficiency")
    put(f"brugg_{s}", math.log(efficiency) / math.log(porosity), "ln(transport efficiency) / ln(porosity)")


def _diffusivity(d: float | Function, where: str) -> tuple[float, Function | None]:
    """(D at θ = 0.5, D(θ)/D(0.5) or None for a constant)."""
    if isinstance(d, float):
        return d, None
    d_ref = float(evaluate(d, 0.5))
    if not math.isfinite(d_ref) or d_ref <= 0:
        raise InputError(f"{where}: the diffusivity at stoichiometry 0.5 must be positive, got {d_ref:g}")
    if isinstance(d, Table):
        return d_ref, Table(d.x, tuple(v / d_ref for v in d.y))
    return d_ref, Expr(f"({d.text})/{d_ref!r}")


def _user_defined(par: Any) -> dict[str, Any]:
    ud = getattr(par, "user_defined", None)
    if ud is None:
        return {}
    return {k: v for k, v in (ud.model_extra or {}).items()}


def _user_value(v: Any) -> Any:
    if isinstance(v, str):
        return str(v)
    if hasattr(v, "x") and hasattr(v, "y"):
        return {"x": list(v.x), "y": list(v.y)}
    return v


def _ocp(e: Any, user: Mapping[str, Any], label: str, where: str) -> tuple[float | Function, str]:
    """The OCP, or the mean of the hysteresis branches when the main OCP is a constant placeholder."""
    main = _function(e.ocp, where + ".OCP [V]")
    branches = [getattr(e, "ocp_lith", None), getattr(e, "ocp_delith", None)]
    note = "native lithiation/delithiation branches"
    if any(b is None for b in branches):
        branches = [
            user.get(f"{label} electrode lithiation OCP [V]"),
            user.get(f"{label} electrode delithiation OCP [V]"),
        ]
        note = "User-defined lithiation/delithiation OCP branches"
    if not isinstance(main, float) or any(b is None for b in branches):
        return main, ""
    lith = _function(branches[0], where + " lithiation OCP")
    delith = _function(branches[1], where + " delithiation OCP")
    return _mean(lith, delith), f"mean of the {note}: hysteresis is not modelled"


def _mean(a: float | Function, b: float | Function) -> Function:
    if isinstance(a, Expr) and isinstance(b, Expr):
        return Expr(f"0.5*(({a.text}) + ({b.text}))")
    xs = sorted({*(_grid(a)), *(_grid(b))})
    x = np.asarray(xs, float)
    return Table(tuple(x), tuple(0.5 * (np.asarray(evaluate(a, x), float) + np.asarray(evaluate(b, x), float))))


def _grid(f: float | Function) -> Iterable[float]:
    return f.x if isinstance(f, Table) else _STO_GRID


# --- writing ---------------------------------------------------------------------------------------------
def write_bpx(cell: Cell, path: str | Path, **extra: Any) -> Path:
    """Write ``cell`` as BPX JSON (current schema of the installed ``bpx``), validated before writing.

    ``extra`` (e.g. ``confidence_intervals={"D_s_n": (lo, hi)}``, ``fit_report={...}``) is stored under
    "User-defined": numbers as they are, mappings and sequences flattened into "<name>: <key> [i]" entries,
    booleans as 0/1; texts are appended to the header's Description (PyBaMM takes User-defined entries as
    parameters and refuses texts there).
    """
    import bpx

    path = Path(path)
    v = cell.values
    n0, n1, p0, p1 = cell.stoichiometry_window()
    c_e0 = float(v["c_e0"])
    area = float(v["A"])
    stack = area * (float(v["L_n"]) + float(v["L_s"]) + float(v["L_p"]))
    c_tot = float(v["C1"]) + float(v["C2"])
    a_ext = 6.0 * stack ** (2.0 / 3.0)
    header: dict[str, Any] = {"BPX": bpx.__version__, "Title": cell.name, "Model": "DFN"}
    if cell.description:
        header["Description"] = cell.description
    refs = sorted({s for s in cell.sources.values() if s})
    if refs:
        header["References"] = "; ".join(refs)[:20000]

    def electrode(s: str) -> dict[str, Any]:
        eps_s, r_s, c_max = float(v[f"eps_s_{s}"]), float(v[f"R_s_{s}"]), float(v[f"c_max_{s}"])
        eps_e = float(v[f"eps_e_{s}"])
        d = _product(float(v[f"D_s_{s}"]), v.get(f"D_s_{s}_shape"))
        out: dict[str, Any] = {
            "Thickness [m]": float(v[f"L_{s}"]),
            "Porosity": eps_e,
            "Transport efficiency": float(v[f"B_{s}"]) if f"B_{s}" in v else eps_e ** float(v[f"brugg_{s}"]),
            "Conductivity [S.m-1]": float(v[f"sigma_{s}"]) * eps_s ** float(v[f"brugg_s_{s}"]),
            "Particle radius [m]": r_s,
            "Surface area per unit volume [m-1]": 3.0 * eps_s / r_s,
            "Maximum concentration [mol.m-3]": c_max,
            "Diffusivity [m2.s-1]": _bpx_function(d, _STO_GRID),
            "Diffusivity activation energy [J.mol-1]": float(v[f"E_D_s_{s}"]),
            "OCP [V]": _bpx_function(v[f"U_{s}"], _STO_GRID),
            "Entropic change coefficient [V.K-1]": _bpx_function(v[f"dUdT_{s}"], _STO_GRID),
            "Reaction rate constant [mol.m-2.s-1]": float(v[f"k_{s}"]) * c_max * math.sqrt(c_e0) / F,
            "Reaction rate constant activation energy [J.mol-1]": float(v[f"E_k_{s}"]),
        }
        lo, hi = (n0, n1) if s == "n" else (p1, p0)
        out["Minimum stoichiometry"] = float(lo)
        out["Maximum stoichiometry"] = float(hi)
        return out

    eps_e_s = float(v["eps_e_s"])
    user: dict[str, Any] = {EXT_VERSION: 1, EXT_WINDOW: int("sto_n_0" not in v)}
    for key in _EXT_KEYS:
        if key in v:
            val = v[key]
            user[EXT + key] = _bpx_text(val) if isinstance(val, Expr) else to_json(val)
    descriptions: list[str] = []
    for name, value in extra.items():
        _flatten(name, value, user, descriptions)
    if descriptions:  # PyBaMM cannot take texts as parameters: they go to the header's description
        header["Description"] = "; ".join([*([cell.description] if cell.description else []), *descriptions])

    obj: dict[str, Any] = {
        "Header": header,
        "Parameterisation": {
            "Cell": {
                "Electrode area [m2]": area,
                "Number of electrode pairs connected in parallel to make a cell": 1,
                "Lower voltage cut-off [V]": float(v["V_min"]),
                "Upper voltage cut-off [V]": float(v["V_max"]),
                "Nominal cell capacity [A.h]": float(v["Q_nom"]),
                "Reference temperature [K]": float(v["T_ref"]),
                "Volume [m3]": stack,
                "External surface area [m2]": a_ext,
                "Density [kg.m-3]": c_tot / (CP_NOMINAL * stack),
                "Specific heat capacity [J.K-1.kg-1]": CP_NOMINAL,
            },
            "Electrolyte": {
                "Cation transference number": float(v["t_plus"]),
                "Diffusivity [m2.s-1]": _bpx_function(_product(float(v["D_e_scale"]), v["D_e"]), _CE_GRID),
                "Diffusivity activation energy [J.mol-1]": float(v["E_D_e"]),
                "Conductivity [S.m-1]": _bpx_function(_product(float(v["kappa_scale"]), v["kappa"]), _CE_GRID),
                "Conductivity activation energy [J.mol-1]": float(v["E_kappa"]),
            },
            "Negative electrode": electrode("n"),
            "Positive electrode": electrode("p"),
            "Separator": {
                "Thickness [m]": float(v["L_s"]),
                "Porosity": eps_e_s,
                "Transport efficiency": float(v["B_s"]) if "B_s" in v else eps_e_s ** float(v["brugg_s"]),
            },
            "User-defined": user,
        },
        "State": {
            "Initial conditions": {
                "Initial electrolyte concentration [mol.m-3]": c_e0,
                "Initial temperature [K]": float(v["T_ref"]),
            },
            "Thermal environment": {
                "Ambient temperature [K]": float(v["T_ref"]),
                "Heat transfer coefficient [W.m-2.K-1]": float(v["h2a"]) / a_ext,
            },
        },
    }
    _validate(json.loads(json.dumps(obj)), f"BPX export of cell {cell.name!r}")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(obj, indent=2) + "\n", encoding="utf-8")
    return path


def _product(scale: float, f: float | Function | None) -> float | Function:
    """scale × f (f a number, an expression, a table or None for 1)."""
    if f is None:
        return scale
    if isinstance(f, float | int):
        return scale * float(f)
    if scale == 1.0:
        return f
    if isinstance(f, Table):
        return Table(f.x, tuple(scale * y for y in f.y))
    return Expr(f"{scale!r}*({f.text})")


def _bpx_function(f: float | Function, grid: np.ndarray) -> Any:
    """A BPX value PyBaMM can use: a number, an expression in exp/tanh/cosh, else a table on ``grid``."""
    if isinstance(f, float | int):
        return float(f)
    if isinstance(f, Expr) and _call_names(f) <= PYBAMM_FUNCTIONS:
        return _bpx_text(f)
    if isinstance(f, Table):
        return to_json(f)
    y = np.asarray(evaluate(f, grid), float)
    return {"x": [float(t) for t in grid], "y": [float(t) for t in y]}


def _call_names(f: Expr) -> set[str]:
    tree = ast.parse(f.text, mode="eval")
    return {n.func.id for n in ast.walk(tree) if isinstance(n, ast.Call) and isinstance(n.func, ast.Name)}


class _Inline(ast.NodeTransformer):
    """Replace the named constants pi and e by numbers (BPX functions know only the variable x)."""

    def visit_Name(self, node: ast.Name) -> ast.AST:
        if node.id in _CONSTANTS:
            return ast.copy_location(ast.Constant(_CONSTANTS[node.id]), node)
        return node


def _bpx_text(f: Expr) -> str:
    """The expression in BPX syntax: its own text unless it names a constant."""
    tree = ast.parse(f.text, mode="eval")
    if not any(isinstance(n, ast.Name) and n.id in _CONSTANTS for n in ast.walk(tree)):
        return f.text
    return ast.unparse(_Inline().visit(tree))


def _flatten(name: str, value: Any, out: dict[str, Any], texts: list[str]) -> None:
    """Store ``value`` under User-defined as numbers (BPX accepts numbers, functions and tables only)."""
    if value is None:
        return
    if isinstance(value, bool | np.bool_):
        out[name] = int(bool(value))
    elif isinstance(value, int | float | np.integer | np.floating):
        x = float(value)
        if not math.isfinite(x):
            texts.append(f"{name}: {x}")
        else:
            out[name] = x
    elif isinstance(value, str):
        texts.append(f"{name}: {value}")
    elif isinstance(value, Mapping):
        for k, sub in value.items():
            _flatten(f"{name}: {k}", sub, out, texts)
    elif isinstance(value, Iterable):
        for i, sub in enumerate(value):
            _flatten(f"{name} [{i}]", sub, out, texts)
    else:
        raise InputError(
            f"BPX export: extra metadata {name!r} must be numbers, texts, mappings or sequences, "
            f"got {type(value).__name__}"
        )


__all__ = ["read_bpx", "write_bpx", "EXT"]
