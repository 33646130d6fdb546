"""Cells: immutable sets of parameter values (numbers and functions), loaded from built-ins, TOML or BPX.

A :class:`Cell` holds every value the DFN–thermal model needs, keyed by the ASCII names of :data:`KEYS`, with
the source of each literature value. The 18 identified parameters keep the names of
:mod:`battlab.parameters`. Cells are values: :meth:`Cell.with_values` returns a new cell.
"""

from __future__ import annotations

import hashlib
import json
import math
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
from scipy.optimize import brentq

from battlab import causes, parameters
from battlab.constants import R_GAS, F
from battlab.functions import Expr, Function, Table, as_function, evaluate, to_json
from protocols.errors import InputError
from protocols.steps import did_you_mean


@dataclass(frozen=True)
class Key:
    """One model input: unit, meaning, whether it is a function (of which variable) and whether required."""

    unit: str
    meaning: str
    function_of: str | None = None  # "sto" (stoichiometry) or "c_e" [mol/m3]
    required: bool = True
    positive: bool = True  # a value ≤ 0 is physically impossible
    fraction: bool = False  # must lie in (0, 1)
    default: float | None = None  # taken when an optional key is absent


def _electrode(s: str, name: str) -> dict[str, Key]:
    return {
        f"L_{s}": Key("m", f"{name} thickness"),
        f"eps_s_{s}": Key("1", f"{name} active material volume fraction", fraction=True),
        f"eps_e_{s}": Key("1", f"{name} electrolyte volume fraction (porosity)", fraction=True),
        f"R_s_{s}": Key("m", f"{name} particle radius"),
        f"c_max_{s}": Key("mol/m3", f"{name} maximum lithium concentration"),
        f"D_s_{s}": Key("m2/s", f"{name} solid diffusivity at T_ref"),
        f"D_s_{s}_shape": Key("1", f"{name} solid diffusivity factor vs stoichiometry", "sto", required=False),
        f"sigma_{s}": Key("S/m", f"{name} solid conductivity"),
        f"brugg_s_{s}": Key("1", f"{name} Bruggeman exponent of the solid (0: conductivity as given)", positive=False),
        f"brugg_{s}": Key("1", f"{name} Bruggeman exponent of the electrolyte"),
        f"B_{s}": Key("1", f"{name} electrolyte transport efficiency (overrides Bruggeman)", required=False),
        f"k_{s}": Key("A/m2 (m3/mol)^1.5", f"{name} reaction rate constant at T_ref (eq. A18)"),
        f"R_f_{s}": Key("Ohm m2", f"{name} film resistance (eq. A19)", positive=False),
        f"E_R_f_{s}": Key(
            "J/mol",
            f"{name} activation energy of the film's conductance (B5: R_f falls as T rises; absent: 0)",
            required=False,
            positive=False,
            default=0.0,
        ),
        f"U_{s}": Key("V", f"{name} open-circuit potential at T_ref", "sto"),
        f"dUdT_{s}": Key("V/K", f"{name} entropic coefficient", "sto", positive=False),
        f"E_D_s_{s}": Key("J/mol", f"{name} activation energy of D_s (eq. B5)", positive=False),
        f"E_k_{s}": Key("J/mol", f"{name} activation energy of k (eq. B5)", positive=False),
    }


#: Every model input. Values are SI; temperatures in K.
KEYS: dict[str, Key] = {
    **_electrode("n", "negative electrode"),
    **_electrode("p", "positive electrode"),
    "L_s": Key("m", "separator thickness"),
    "eps_e_s": Key("1", "separator electrolyte volume fraction", fraction=True),
    "brugg_s": Key("1", "separator Bruggeman exponent"),
    "B_s": Key("1", "separator transport efficiency (overrides Bruggeman)", required=False),
    "A": Key("m2", "electrode area (all layers in parallel)"),
    "c_e0": Key("mol/m3", "initial electrolyte concentration"),
    "t_plus": Key("1", "cation transference number", fraction=True),
    "D_e": Key("m2/s", "electrolyte diffusivity at T_ref", "c_e"),
    "kappa": Key("S/m", "electrolyte conductivity at T_ref", "c_e"),
    "dlnf": Key("1", "d ln f / d ln c_e (eq. A11)", "c_e", positive=False),
    "D_e_scale": Key("1", "factor on D_e(c_e)"),
    "kappa_scale": Key("1", "factor on kappa(c_e)"),
    "dlnf_scale": Key("1", "factor on d ln f / d ln c_e", positive=False),
    "E_D_e": Key("J/mol", "activation energy of D_e (eq. B5)", positive=False),
    "E_kappa": Key("J/mol", "activation energy of kappa (eq. B5)", positive=False),
    "T_ref": Key("K", "reference temperature"),
    "C1": Key("J/K", "heat capacity of the core (eq. B1)"),
    "C2": Key("J/K", "heat capacity of the surface (eq. B2)"),
    "h12": Key("W/K", "core-to-surface heat transfer (eq. B1)"),
    "h2a": Key("W/K", "surface-to-ambient heat transfer (eq. B2); 0 = adiabatic", positive=False),
    "R_c": Key("Ohm", "contact resistance (eq. A21)", positive=False),
    "V_min": Key("V", "lower voltage cut-off"),
    "V_max": Key("V", "upper voltage cut-off"),
    "Q_nom": Key("A h", "nominal capacity (defines 1C)"),
    "T_max": Key("K", "maximum surface temperature"),
    "n_Li": Key("mol", "cyclable lithium in the solid phase (eq. 10)", required=False),
    "sto_n_0": Key("1", "negative stoichiometry at 0 % SOC", required=False, fraction=True),
    "sto_n_100": Key("1", "negative stoichiometry at 100 % SOC", required=False, fraction=True),
    "sto_p_0": Key("1", "positive stoichiometry at 0 % SOC", required=False, fraction=True),
    "sto_p_100": Key("1", "positive stoichiometry at 100 % SOC", required=False, fraction=True),
}

Value = float | Function


def _check_value(key: str, value: Any) -> Value:
    if key not in KEYS:
        raise InputError(f"unknown cell parameter {key!r}")
    spec = KEYS[key]
    try:
        v = as_function(value, ("x",))
    except InputError as exc:
        raise InputError(f"cell parameter {key}: {exc}") from None
    if isinstance(v, float):
        if not math.isfinite(v):
            raise InputError(f"cell parameter {key}: expected a finite number [{spec.unit}], got {value!r}")
        if spec.positive and v <= 0:
            raise InputError(f"cell parameter {key} ({spec.meaning}) must be positive [{spec.unit}], got {v:g}")
        if not spec.positive and key.startswith(("R_f", "R_c", "h2a")) and v < 0:
            raise InputError(f"cell parameter {key} ({spec.meaning}) must be ≥ 0 [{spec.unit}], got {v:g}")
        if spec.fraction and not 0.0 < v < 1.0:
            raise InputError(f"cell parameter {key} ({spec.meaning}) must lie in (0, 1), got {v:g}")
    elif spec.function_of is None:
        raise InputError(f"cell parameter {key} ({spec.meaning}) must be a number [{spec.unit}], got a function")
    return v


@dataclass(frozen=True)
class CellFormat:
    """A cell file format: ``read(path) -> Cell`` and ``write(cell, path, **extra) -> path``."""

    read: Callable[[Path], Cell]
    write: Callable[..., Path]


#: Cell file formats by name. The I/O modules that implement them register themselves
#: (:mod:`battlab.io.bpx` registers ``"bpx"`` when :mod:`battlab` is imported), so that cells need not import
#: the readers that build them.
_FORMATS: dict[str, CellFormat] = {}


def register_format(name: str, read: Callable[[Path], Cell], write: Callable[..., Path]) -> None:
    """Make a cell file format available to :meth:`Cell.load`, :meth:`Cell.from_bpx` and :meth:`Cell.to_bpx`."""
    _FORMATS[name] = CellFormat(read, write)


def _format(name: str) -> CellFormat:
    try:
        return _FORMATS[name]
    except KeyError:
        raise InputError(f"cell format {name!r} is not available (import battlab to register it)") from None


@dataclass(frozen=True, eq=False)
class Cell:
    """An immutable cell: ``values[key]`` is a number (SI) or a function; ``sources[key]`` cites it."""

    name: str
    values: Mapping[str, Value]
    sources: Mapping[str, str] = field(default_factory=dict)
    description: str = ""
    #: model extensions switched on: catalog key → {parameter name: value (SI)}, every parameter present
    extensions: Mapping[str, Mapping[str, float]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        vals = {k: _check_value(k, v) for k, v in self.values.items()}
        vals |= {k: s.default for k, s in KEYS.items() if s.default is not None and k not in vals}
        missing = [k for k, s in KEYS.items() if s.required and k not in vals]
        if missing:
            raise InputError(f"cell {self.name!r}: missing parameter(s) {', '.join(missing)}")
        windows = [k for k in ("sto_n_0", "sto_n_100", "sto_p_0", "sto_p_100") if k in vals]
        if windows and len(windows) != 4:
            raise InputError(f"cell {self.name!r}: give all four stoichiometry limits or none, got {windows}")
        if not windows and "n_Li" not in vals:
            raise InputError(f"cell {self.name!r}: needs n_Li or the four stoichiometry limits sto_*_0/100")
        for s in ("n", "p"):
            total = vals[f"eps_s_{s}"] + vals[f"eps_e_{s}"]
            if total >= 1.0:
                raise InputError(f"cell {self.name!r}: eps_s_{s} + eps_e_{s} = {total:g} must be below 1")
        if vals["V_min"] >= vals["V_max"]:
            raise InputError(f"cell {self.name!r}: V_min {vals['V_min']} must be below V_max {vals['V_max']}")
        object.__setattr__(self, "values", MappingProxyType(vals))
        object.__setattr__(self, "sources", MappingProxyType(dict(self.sources)))
        exts = {k: _check_extension(self.name, k, v) for k, v in dict(self.extensions).items()}
        order = list(parameters.EXTENSIONS)
        ordered = {k: MappingProxyType(exts[k]) for k in sorted(exts, key=order.index)}
        clash = causes.slot_conflicts(list(ordered))
        if clash:
            a, b, slot = clash[0]
            raise InputError(f"cell {self.name!r}: extensions {a!r} and {b!r} both change the model's {slot}")
        object.__setattr__(self, "extensions", MappingProxyType(ordered))

    def __reduce__(self) -> tuple:
        """Cells pickle (for worker processes and Dask) as their plain values."""
        exts = {k: dict(v) for k, v in self.extensions.items()}
        return (Cell, (self.name, dict(self.values), dict(self.sources), self.description, exts))

    # --- construction ---------------------------------------------------------------------------------
    @classmethod
    def load(cls, name_or_path: str | Path) -> Cell:
        """A built-in cell (``nca18650``, ``nca18650-true``), a cell TOML file or a BPX JSON file; any of them followed
        by catalog extensions switched on, ``CELL+KEY[:NAME=VALUE,...]+...`` (e.g. a virtual truth that hides an
        effect: ``nca18650-true+contact_resistance:R_c=0.005``)."""
        text = str(name_or_path)
        if "+" in text and not Path(text).exists():
            return _with_extension_specs(text)
        if text == "nca18650-true":
            base = cls.load("nca18650")
            cell = base.with_values(**{p.name: p.truth for p in parameters.DYNAMIC})
            return cell.renamed("nca18650-true", "the paper's cell at its Table 11 identified values")
        builtin = resources.files("battlab.cells").joinpath(f"{text}.toml")
        if builtin.is_file():
            with builtin.open("rb") as fh:
                return cls._from_toml_dict(tomllib.load(fh), text)
        path = Path(text)
        if not path.exists():
            names = sorted(
                p.name.removesuffix(".toml")
                for p in resources.files("battlab.cells").iterdir()
                if p.name.endswith(".toml")
            )
            names.append("nca18650-true")
            raise InputError(
                f"cell {text!r}{did_you_mean(text, names)}: not a built-in cell ({', '.join(names)}) nor a file"
            )
        if path.suffix == ".json":
            return cls.from_bpx(path)
        if path.suffix == ".toml":
            try:
                data = tomllib.loads(path.read_text())
            except tomllib.TOMLDecodeError as exc:
                raise InputError(f"{path}: not valid TOML ({exc})") from None
            return cls._from_toml_dict(data, str(path))
        raise InputError(f"{path}: expected a BPX .json or a cell .toml file")

    @classmethod
    def _from_toml_dict(cls, data: dict[str, Any], where: str) -> Cell:
        params = data.get("parameters")
        if not isinstance(params, dict):
            raise InputError(f"{where}: missing [parameters] table")
        values: dict[str, Any] = {}
        sources: dict[str, str] = {}
        for key, entry in params.items():
            if isinstance(entry, dict) and "value" in entry:
                values[key] = entry["value"]
                if "source" in entry:
                    sources[key] = str(entry["source"])
            else:
                values[key] = entry
        try:
            return cls(str(data.get("name", where)), values, sources, str(data.get("description", "")))
        except InputError as exc:
            raise InputError(f"{where}: {exc}") from None

    @classmethod
    def from_bpx(cls, path: str | Path, *, target_soc: float | None = None) -> Cell:
        """Read a BPX JSON file (validated by the ``bpx`` package); see :mod:`battlab.io.bpx`."""
        return _format("bpx").read(Path(path))

    def to_bpx(self, path: str | Path, **extra: Any) -> Path:
        """Write the cell as BPX JSON (validated by the ``bpx`` package); see :mod:`battlab.io.bpx`."""
        return _format("bpx").write(self, Path(path), **extra)

    def to_toml_dict(self) -> dict[str, Any]:
        """The TOML representation read by :meth:`load`."""
        params: dict[str, Any] = {}
        for k, v in self.values.items():
            entry: dict[str, Any] = {"value": to_json(v)}
            if k in self.sources:
                entry["source"] = self.sources[k]
            params[k] = entry
        return {"name": self.name, "description": self.description, "parameters": params}

    # --- values ---------------------------------------------------------------------------------------
    def __getitem__(self, key: str) -> Value:
        try:
            return self.values[key]
        except KeyError:
            raise InputError(f"cell {self.name!r} has no parameter {key!r}") from None

    def get(self, key: str, default: Value | None = None) -> Value | None:
        return self.values.get(key, default)

    def with_values(self, **updates: Any) -> Cell:
        """A new cell with some values replaced; unknown names and impossible values are errors. An extension's
        parameter may be given as ``KEY.NAME`` (the extension must be on)."""
        ext_updates: dict[str, dict[str, Any]] = {}
        for k in list(updates):
            if k in KEYS:
                continue
            if k in parameters.EXTENSION_SPECS:
                sp = parameters.EXTENSION_SPECS[k]
                if sp.extension not in self.extensions:
                    raise InputError(f"parameter {k!r}: the extension {sp.extension!r} is not on in cell {self.name!r}")
                ext_updates.setdefault(sp.extension, {})[sp.name] = updates.pop(k)
                continue
            raise InputError(f"unknown parameter {k!r}; dynamic parameters are {', '.join(parameters.NAMES)}")
        vals = dict(self.values)
        vals.update(updates)
        src = {k: v for k, v in self.sources.items() if k not in updates}
        exts = {k: {**v, **ext_updates.get(k, {})} for k, v in self.extensions.items()}
        return Cell(self.name, vals, src, self.description, exts)

    def with_ocp(self, electrode: str, curve: Table, source: str = "a table") -> Cell:
        """A new cell whose electrode ``"n"`` or ``"p"`` has the open-circuit potential ``curve`` (U vs Li/Li⁺ [V]
        over stoichiometry, e.g. a half-cell measurement: :func:`battlab.io.ocp.read_ocp_csv`). The curve must
        cover the electrode's stoichiometry window in the new cell (a table is flat beyond its ends: no OCP there);
        ``source`` names it in that error. The entropic coefficient dU/dT stays the cell's."""
        if electrode not in ("n", "p"):
            raise InputError(f"OCP electrode must be 'n' (negative) or 'p' (positive), got {electrode!r}")
        if not isinstance(curve, Table):
            raise InputError(f"OCP of electrode {electrode!r}: expected a table of stoichiometry and potential")
        cell = self.with_values(**{f"U_{electrode}": curve})
        side = "negative" if electrode == "n" else "positive"
        try:  # from the lithium inventory and the voltage limits, unless the cell gives it
            n0, n1, p0, p1 = cell.stoichiometry_window()
        except InputError as exc:
            raise InputError(f"{source}: with this {side} OCP, {exc}") from None
        lo, hi = (min(n0, n1), max(n0, n1)) if electrode == "n" else (min(p0, p1), max(p0, p1))
        if lo < curve.x[0] - 1e-9 or hi > curve.x[-1] + 1e-9:
            raise InputError(
                f"{source}: the {side} OCP covers stoichiometry {curve.x[0]:.4f}-{curve.x[-1]:.4f}, but cell "
                f"{self.name!r} uses {lo:.4f}-{hi:.4f} of it between 0 and 100 % SOC"
            )
        return cell

    def with_extension(self, key: str, **values: float) -> Cell:
        """A new cell with the catalog extension ``key`` on (see :data:`battlab.parameters.EXTENSIONS`), its
        parameters at ``values`` [SI] and the rest at their earlier values, or their "off" values (with which
        the model is the base model exactly)."""
        exts = {k: dict(v) for k, v in self.extensions.items()}
        exts[key] = {**exts.get(key, {}), **values}
        return Cell(self.name, self.values, self.sources, self.description, exts)

    def without_extension(self, key: str) -> Cell:
        """A new cell with the extension ``key`` off."""
        exts = {k: dict(v) for k, v in self.extensions.items() if k != key}
        return Cell(self.name, self.values, self.sources, self.description, exts)

    def renamed(self, name: str, description: str | None = None) -> Cell:
        desc = self.description if description is None else description
        return Cell(name, self.values, self.sources, desc, {k: dict(v) for k, v in self.extensions.items()})

    def parameter_names(self) -> tuple[str, ...]:
        """The identified parameters of this cell's model: the 18, then each extension's ``KEY.NAME`` (the order
        of θ̄ in the compiled model)."""
        ext = tuple(p.qualified for k in self.extensions for p in parameters.EXTENSIONS[k])
        return parameters.NAMES + ext

    def theta_bar(self) -> np.ndarray:
        """θ̄ of every identified parameter, in :meth:`parameter_names` order."""
        return np.array([self.normalised(n) for n in self.parameter_names()])

    def value(self, name: str) -> float:
        """The value of an identified parameter (one of the 18 or ``KEY.NAME`` of an extension that is on)."""
        if name in parameters.EXTENSION_SPECS:
            sp = parameters.EXTENSION_SPECS[name]
            if sp.extension not in self.extensions:
                raise InputError(f"parameter {name!r}: the extension {sp.extension!r} is not on in cell {self.name!r}")
            return float(self.extensions[sp.extension][sp.name])
        return float(self[name])

    def normalised(self, name: str) -> float:
        """θ̄ of an identified parameter (eq. 1); may lie outside [0, 1]."""
        return parameters.spec(name).normalise(self.value(name))

    def with_normalised(self, **updates: float) -> Cell:
        """A new cell with identified parameters set from θ̄ (eq. 1)."""
        return self.with_values(**{k: parameters.spec(k).denormalise(float(v)) for k, v in updates.items()})

    def dynamic_values(self) -> dict[str, float]:
        return {n: float(self[n]) for n in parameters.NAMES}

    def hash(self) -> str:
        """SHA-256 of the canonical JSON of all values (keys sorted) and the extensions: identifies the
        parameter set."""
        data: dict[str, Any] = {k: to_json(v) for k, v in sorted(self.values.items())}
        if self.extensions:
            data["extensions"] = {k: dict(v) for k, v in self.extensions.items()}
        blob = json.dumps(data, sort_keys=True)
        return hashlib.sha256(blob.encode()).hexdigest()

    def static_hash(self) -> str:
        """The hash of every value except the identified parameters (which the compiled model takes as inputs),
        with the set of extensions that are on (they change the equations): cells that differ only in identified
        values share one model."""
        return self._hash_without(set(parameters.NAMES))

    def structure_hash(self) -> str:
        """The hash of what the compiled model's code is made from: :meth:`static_hash` without the values it takes
        as inputs (:data:`battlab.parameters.MODEL_INPUTS`) or never reads
        (:data:`battlab.parameters.START_STATE_ONLY`), so an equilibrium fit's trial cells share one library."""
        skip = set(parameters.NAMES) | set(parameters.MODEL_INPUTS) | set(parameters.START_STATE_ONLY)
        return self._hash_without(skip)

    def _hash_without(self, skip: set[str]) -> str:
        data: dict[str, Any] = {k: to_json(v) for k, v in sorted(self.values.items()) if k not in skip}
        if self.extensions:
            data["extensions"] = list(self.extensions)
        return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()

    # --- equilibrium ----------------------------------------------------------------------------------
    def fn(self, key: str, x: Any, backend: str = "numpy") -> Any:
        """Evaluate a function-valued parameter (or a constant) at ``x``."""
        return evaluate(self[key], x, backend)

    def electrode_moles(self, s: str) -> float:
        """H± = ε_s L A c_max [mol] (eq. 11)."""
        return float(self[f"eps_s_{s}"]) * float(self[f"L_{s}"]) * float(self["A"]) * float(self[f"c_max_{s}"])

    def stoichiometry_window(self) -> tuple[float, float, float, float]:
        """(θ⁻ at 0 %, θ⁻ at 100 %, θ⁺ at 0 %, θ⁺ at 100 %): given, or from n_Li and the limits (eqs. 10, 20)."""
        if "sto_n_0" in self.values:
            n0, n1, p0, p1 = (float(self[k]) for k in ("sto_n_0", "sto_n_100", "sto_p_0", "sto_p_100"))
            return n0, n1, p0, p1
        return _window_from_lithium(self)

    def stoichiometry(self, soc: float) -> tuple[float, float]:
        """(θ⁻, θ⁺) at a state of charge, linear in each electrode between its 0 % and 100 % points (eq. 20)."""
        if not 0.0 <= soc <= 1.0 or not math.isfinite(soc):
            raise InputError(f"SOC must be in [0, 1], got {soc}")
        n0, n1, p0, p1 = self.stoichiometry_window()
        return n0 + soc * (n1 - n0), p0 + soc * (p1 - p0)

    def ocv(self, soc: Any) -> Any:
        """Open-circuit voltage U⁺(θ⁺) − U⁻(θ⁻) at T_ref [V] (eq. 14)."""
        n0, n1, p0, p1 = self.stoichiometry_window()
        soc = np.asarray(soc, float)
        return self.fn("U_p", p0 + soc * (p1 - p0)) - self.fn("U_n", n0 + soc * (n1 - n0))

    def soc_from_voltage(self, voltage: float) -> float:
        """The SOC whose OCV equals a rest voltage [V]; outside the OCV range is an error."""
        lo, hi = float(self.ocv(0.0)), float(self.ocv(1.0))
        if not lo - 1e-9 <= voltage <= hi + 1e-9:
            raise InputError(f"rest voltage {voltage:.4f} V is outside the cell's OCV range [{lo:.4f}, {hi:.4f}] V")
        if voltage <= lo:
            return 0.0
        if voltage >= hi:
            return 1.0
        return float(brentq(lambda s: float(self.ocv(s)) - voltage, 0.0, 1.0, xtol=1e-12))

    def capacity(self) -> float:
        """Capacity between 0 % and 100 % SOC at equilibrium [A h] (eq. 21, in A h)."""
        n0, n1, _, _ = self.stoichiometry_window()
        return abs(n1 - n0) * self.electrode_moles("n") * F / 3600.0

    def lithium_moles(self) -> float:
        """Cyclable lithium in the solid at the window's stoichiometries [mol] (eq. 10)."""
        if "n_Li" in self.values:
            return float(self["n_Li"])
        n0, _, p0, _ = self.stoichiometry_window()
        return self.electrode_moles("n") * n0 + self.electrode_moles("p") * p0


def _with_extension_specs(text: str) -> Cell:
    """``CELL+KEY[:NAME=VALUE,...]+...``: the cell with those catalog extensions on (one error naming the part)."""
    base, *specs = text.split("+")
    cell = Cell.load(base)
    for spec in specs:
        key, _, body = spec.partition(":")
        values: dict[str, float] = {}
        for item in filter(None, (x.strip() for x in body.split(","))):
            name, eq, value = item.partition("=")
            try:
                values[name.strip()] = float(value)
            except ValueError:
                raise InputError(f"cell {text!r}: {item!r} is not NAME=VALUE with a number") from None
            if not eq:
                raise InputError(f"cell {text!r}: {item!r} is not NAME=VALUE")
        cell = cell.with_extension(key.strip(), **values)
    return cell.renamed(text)


def _check_extension(cell: str, key: str, values: Mapping[str, Any]) -> dict[str, float]:
    """An extension's values, complete (missing ones at "off") and finite; unknown keys and names are errors."""
    specs = parameters.extension_parameters(key)
    known = {p.name: p for p in specs}
    out = {p.name: p.off for p in specs}
    for name, v in dict(values).items():
        if name not in known:
            raise InputError(f"cell {cell!r}: extension {key!r} has no parameter {name!r}; expected {', '.join(known)}")
        try:
            x = float(v)
        except (TypeError, ValueError):
            x = math.nan
        if not math.isfinite(x):
            raise InputError(f"cell {cell!r}: extension {key}: {name} must be a finite number [{known[name].unit}]")
        out[name] = x
    if key == "current_sensor" and out["gain"] <= -1.0:
        raise InputError(f"cell {cell!r}: extension current_sensor: gain must be above -1, got {out['gain']:g}")
    return out


def rest_stoichiometries(
    cell: Cell, n_li: float, voltage: float, *, capacity: float = 1.0, clamp: bool = False
) -> tuple[float, float]:
    """(θ⁻, θ⁺) at rest at the open-circuit ``voltage`` [V] with ``n_li`` [mol] of cyclable lithium in electrodes of
    ``capacity`` times the cell's moles H±: U⁺(θ⁺) − U⁻(θ⁻) = V, H⁻θ⁻ + H⁺θ⁺ = n_Li (eqs. 10, 11, 14, 15). No such
    state: :class:`InputError`, or with ``clamp`` the end of the stoichiometry range nearest to that voltage (an
    electrode full or empty first)."""
    hn, hp = capacity * cell.electrode_moles("n"), capacity * cell.electrode_moles("p")

    def theta_p(tn: float) -> float:
        return (n_li - hn * tn) / hp

    def ocv(tn: float) -> float:
        return float(cell.fn("U_p", theta_p(tn)) - cell.fn("U_n", tn))

    # θ⁻ range where both stoichiometries are within (0, 1)
    lo = max(1e-6, (n_li - hp * (1 - 1e-6)) / hn)
    hi = min(1 - 1e-6, (n_li - hp * 1e-6) / hn)
    if lo >= hi:
        raise InputError(
            f"cell {cell.name!r}: n_Li = {n_li:.5g} mol does not fit electrodes of {capacity:.4g} times its capacities"
        )
    if clamp and voltage <= ocv(lo):
        return float(lo), float(theta_p(lo))
    if clamp and voltage >= ocv(hi):
        return float(hi), float(theta_p(hi))
    try:
        tn = brentq(lambda t: ocv(t) - voltage, lo, hi, xtol=1e-14)
    except ValueError:
        raise InputError(
            f"cell {cell.name!r}: the OCV does not reach {voltage:.4f} V for n_Li = {n_li:.5g} mol and "
            f"{capacity:.4g} times its capacities (range {ocv(lo):.3f}–{ocv(hi):.3f} V)"
        ) from None
    return float(tn), float(theta_p(tn))


def _window_from_lithium(cell: Cell) -> tuple[float, float, float, float]:
    """θ± at V_min and V_max from the cell's n_Li (eqs. 10, 15, 18, 20)."""
    n0, p0 = rest_stoichiometries(cell, float(cell["n_Li"]), float(cell["V_min"]))
    n1, p1 = rest_stoichiometries(cell, float(cell["n_Li"]), float(cell["V_max"]))
    return n0, n1, p0, p1


__all__ = ["Cell", "KEYS", "Key", "F", "R_GAS", "Expr", "Table"]
