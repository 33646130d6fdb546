"""BPX JSON → :class:`~battlab.cell.Cell`, following PyBaMM's BPX importer (see :mod:`battlab.io.bpx`)."""

from __future__ import annotations

import json
import math
import re
import warnings
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from battlab.cell import Cell, F
from battlab.functions import Expr, Function, Table, as_function, evaluate
from battlab.io.bpx.common import (
    C_E0_DEFAULT,
    CORE_SURFACE_TAU,
    EXT,
    EXT_KEYS,
    EXT_MODEL,
    EXT_VERSION,
    EXT_WINDOW,
    RHO_CP_DEFAULT,
    STO_GRID,
    SURFACE_FRACTION,
    T_MAX_DEFAULT,
    T_REF_DEFAULT,
)
from protocols.errors import InputError


# --- reading ---------------------------------------------------------------------------------------------
def read_bpx(path: str | Path) -> Cell:
    """Read and validate a BPX JSON file (``bpx`` package; v0.x files are migrated) into a :class:`Cell`."""
    path = Path(path)
    raw = _load_json(path)
    model = validate(raw, str(path))
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
        put(f"E_R_f_{s}", 0.0, "BPX has no film resistance")
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
        for key in EXT_KEYS:
            if EXT + key in user:
                try:
                    values[key] = as_function(_user_value(user[EXT + key]))
                except InputError as exc:
                    raise InputError(f"{path}: BPX field Parameterisation.User-defined.{EXT + key}: {exc}") from None
                sources[key] = src + " (battlab extension)"
    extensions: dict[str, dict[str, float]] = {}
    for entry, x in user.items():
        if entry.startswith(EXT_MODEL):
            key, _, name = entry.removeprefix(EXT_MODEL).partition(".")
            extensions.setdefault(key, {})[name] = _user_value(x)
    header = model.header
    desc = " ".join(t for t in (header.title, header.description) if t)
    try:
        return Cell(path.stem, values, sources, desc, extensions)
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


_GRAMMAR = " (numbers, x, + - * / ** and calls such as exp(), tanh())"


def validate(raw: dict[str, Any], where: str) -> Any:
    """Validate with the ``bpx`` package; any failure becomes one line naming the field."""
    import bpx
    from pydantic import ValidationError
    from pyparsing import ParseBaseException

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # legacy-migration notes, float version, STO-limit checks
        try:
            return bpx.parse_bpx_obj(raw)
        except ValidationError as exc:
            raise InputError(f"{where}: {_describe(exc)}") from None
        except ParseBaseException as exc:  # bpx lets the parser's fail-fast errors through (e.g. "exec('x')")
            field = _unparsable_function(raw)
            at = f"BPX field {field}: " if field else ""
            msg = f"not a valid BPX function of x at character {exc.loc + 1}{_GRAMMAR}"
            raise InputError(f"{where}: {at}{msg}") from None
        except RecursionError:  # the parser recurses once per parenthesis
            field = _unparsable_function(raw)
            at = f"BPX field {field}: " if field else ""
            raise InputError(f"{where}: {at}a function nested too deeply for the BPX parser") from None
        except (ValueError, TypeError, KeyError, AttributeError) as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise InputError(f"{where}: invalid BPX ({first})") from None


def _unparsable_function(raw: Any, prefix: str = "") -> str | None:
    """The dotted path of the first string under ``Parameterisation`` that bpx's expression parser refuses."""
    from bpx.function import Function as BpxFunction
    from pyparsing import ParseBaseException

    if not prefix:
        raw = raw.get("Parameterisation") if isinstance(raw, Mapping) else None
        prefix = "Parameterisation"
    if not isinstance(raw, Mapping):
        return None
    for key, value in raw.items():
        path = f"{prefix}.{key}"
        if isinstance(value, str) and key != "description":
            try:
                BpxFunction.parser.parse_string(value)
            except (ParseBaseException, RecursionError):
                return path
        elif isinstance(value, Mapping):
            found = _unparsable_function(value, path)
            if found:
                return found
    return None


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
            msg = f"not a valid BPX function of x{at}{_GRAMMAR}"
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
    return f.x if isinstance(f, Table) else STO_GRID
