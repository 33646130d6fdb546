"""Options shared by several commands, spelled the same everywhere, each with one range check and one message.

A numeric option's range is a :class:`Bounds` declared once here (:data:`SOC`, :data:`DT`, :data:`TEMPERATURE`,
:data:`VOLTAGE`, ...); its option factory (:func:`soc0_option`, :func:`dt_option`, :func:`ambient_option`, ...)
states the range in ``--help`` and refuses a value outside it before the command starts, as one line naming the
option and the value (:class:`protocols.errors.InputError`: ``error: --soc0 -0.2: the start SOC must be in [0, 1]``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import click

from protocols.errors import InputError

#: the logged-data files the commands that take DATA read (:func:`battlab.io.data.load_data`), for their ``--help``
DATA_FORMATS = (
    "DATA files: battlab run logs (.h5, .hdf5); Battery Data Format CSV (.csv with the columns 'Test Time / s', "
    "'Voltage / V', 'Current / A' [positive = charge], optionally temperatures and steps, and an optional "
    "<name>.summary.json beside it); Panasonic 18650PF .mat files (Kollmeyer, Mendeley Data)."
)


@dataclass(frozen=True)
class Bounds:
    """The values a numeric option accepts: ``low`` to ``high`` in ``unit`` (an end excluded where ``open_low`` or
    ``open_high``), and the one message that refuses any other."""

    what: str
    unit: str = ""
    low: float = -math.inf
    high: float = math.inf
    open_low: bool = False
    open_high: bool = False

    def describe(self) -> str:
        """The range in words, e.g. ``in [0, 1]``, ``> 0 s``, ``in [-40, 80] degC``."""
        unit = f" {self.unit}" if self.unit else ""
        if math.isfinite(self.low) and math.isfinite(self.high):
            lo, hi = "(" if self.open_low else "[", ")" if self.open_high else "]"
            return f"in {lo}{self.low:g}, {self.high:g}{hi}{unit}"
        if math.isfinite(self.low):
            return f"{'>' if self.open_low else '>='} {self.low:g}{unit}"
        if math.isfinite(self.high):
            return f"{'<' if self.open_high else '<='} {self.high:g}{unit}"
        return "a finite number"

    def contains(self, value: float) -> bool:
        above = value > self.low if self.open_low else value >= self.low
        below = value < self.high if self.open_high else value <= self.high
        return math.isfinite(value) and above and below

    def check(self, option: str, value: float, given: str | None = None) -> float:
        """``value``, or an :class:`InputError` naming ``option`` and the value as given (default: ``value``)."""
        if not self.contains(value):
            raise InputError(
                f"{option} {given if given is not None else f'{value:g}'}: {self.what} must be {self.describe()}"
            )
        return value


#: a state of charge
SOC = Bounds("the start SOC", low=0.0, high=1.0)
#: a resampling step [s]
DT = Bounds("the time step", "s", low=0.0, open_low=True)
#: a temperature a cell is tested or simulated at [degC] (what the virtual tester's chamber and the model cover)
TEMPERATURE = Bounds("the temperature", "degC", low=-40.0, high=80.0)
#: a cell voltage [V]
VOLTAGE = Bounds("a cell voltage", "V", low=0.0, high=10.0)
#: a capacity [Ah]
CAPACITY = Bounds("the capacity", "Ah", low=0.0, open_low=True)
#: a count of function evaluations
EVALUATIONS = Bounds("the number of evaluations", low=1.0)


def _checked(option: str, bounds: Bounds) -> Callable[[click.Context, click.Parameter, Any], Any]:
    def callback(ctx: click.Context, param: click.Parameter, value: Any) -> Any:
        return None if value is None else bounds.check(option, value)

    return callback


def bounded_option(
    option: str,
    bounds: Bounds,
    help: str,
    dest: str | None = None,
    *,
    default: Any = None,
    type: Any = float,
    **kwargs: Any,
) -> Any:
    """A numeric option checked against ``bounds`` (stated at the end of its help); ``dest``: its parameter's name
    when not the option's."""
    return click.option(
        option,
        *((dest,) if dest else ()),
        type=type,
        default=default,
        show_default=default is not None,
        callback=_checked(option, bounds),
        help=f"{help.rstrip('.')}; {bounds.describe()}.",
        **kwargs,
    )


def soc0_option(help: str = "Start SOC of data that do not start at rest", default: float | None = None) -> Any:
    """``--soc0`` in [0, 1]."""
    return bounded_option("--soc0", SOC, help, default=default)


def dt_option(help: str = "Resample to this step [s]", default: float = 1.0) -> Any:
    """``--dt`` > 0 s."""
    return bounded_option("--dt", DT, help, default=default)


def ambient_option(help: str = "Ambient temperature [degC]", default: float | None = 25.0) -> Any:
    """``--ambient DEGC`` (one temperature) in [-40, 80] degC."""
    return bounded_option("--ambient", TEMPERATURE, help, default=default)


def max_iter_option(help: str, default: int) -> Any:
    """``--max-iter N`` >= 1."""
    return bounded_option("--max-iter", EVALUATIONS, help, default=default, type=int)


def parse_ambients(values: Sequence[str]) -> dict[str, float] | None:
    """``--ambient`` values ``FILE=DEGC`` or ``DEGC`` (all files) as {file or "*": kelvin}; a value that is no
    temperature, outside :data:`TEMPERATURE` or given twice is one :class:`InputError`."""
    out: dict[str, float] = {}
    for text in values:
        key, _, value = text.rpartition("=")
        try:
            degc = float(value)
        except ValueError:
            raise InputError(f"--ambient {text!r}: expected DEGC or FILE=DEGC, e.g. 0degC_HWFET.mat=0") from None
        TEMPERATURE.check("--ambient", degc, text)
        key = key or "*"
        if key in out:
            raise InputError(f"--ambient {text!r}: {'all files' if key == '*' else key} given twice")
        out[key] = degc + 273.15
    return out or None


def _ambients_checked(ctx: click.Context, param: click.Parameter, value: tuple[str, ...]) -> tuple[str, ...]:
    parse_ambients(value)
    return value


#: ``--ambient [FILE=]DEGC`` (repeatable) of the commands that read logged data; parsed by :func:`parse_ambients`
AMBIENT_OPTION = click.option(
    "--ambient",
    "ambients",
    multiple=True,
    metavar="[FILE=]DEGC",
    callback=_ambients_checked,
    help="Ambient temperature [degC] of data that do not log it: FILE=DEGC for one file (repeat), DEGC for all; "
    f"{TEMPERATURE.describe()}.",
)


def preparation_option() -> Any:
    """``--preparation DATA=PREP`` (repeatable): the log of a data file's preparation, its unscored lead-in."""
    return click.option(
        "--preparation",
        "preparations",
        multiple=True,
        metavar="DATA=PREP",
        help="PREP is the log of DATA's preparation (a full charge, a rest, the adjustment to the start SOC and a "
        "rest, logged as its own run): DATA starts at the full charge with the preparation simulated unscored, so "
        "that the gradients it leaves in the particles are not taken as a cell at rest; repeat per data file.",
    )


def parse_preparations(values: Sequence[str]) -> tuple[tuple[str, str], ...]:
    """``DATA=PREP`` texts → (DATA, PREP) pairs, each preparation's file checked to exist."""
    from pathlib import Path

    out = []
    for text in values:
        data, sep, prep = text.partition("=")
        if not sep or not data or not prep:
            raise InputError(f"--preparation {text}: expected DATA=PREP (a data file and the log of its preparation)")
        if not Path(prep).is_file():
            raise InputError(f"--preparation {text}: {prep}: no such file")
        out.append((data, prep))
    return tuple(out)


def parse_v_limits(text: str) -> tuple[float, float]:
    """``MIN,MAX`` [V] as (MIN, MAX): two numbers, each a :data:`VOLTAGE`, MIN below MAX."""
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise InputError(f"--v-limits {text!r}: expected MIN,MAX in volts, e.g. 2.5,4.3") from None
    VOLTAGE.check("--v-limits", lo, text)
    VOLTAGE.check("--v-limits", hi, text)
    if not lo < hi:
        raise InputError(f"--v-limits {text}: MIN ({lo:g} V) must be below MAX ({hi:g} V)")
    return lo, hi


def v_limits_option(help: str) -> Any:
    """``--v-limits MIN,MAX`` [V], checked by :func:`parse_v_limits` (the command gets the text)."""

    def callback(ctx: click.Context, param: click.Parameter, value: str | None) -> str | None:
        if value is not None:
            parse_v_limits(value)
        return value

    return click.option("--v-limits", default=None, metavar="MIN,MAX", callback=callback, help=help)


#: the cell physics of a virtual tester: ``dfn`` battlab's DFN-thermal model, ``standin`` the drivers'
#: equivalent-circuit cell (fast, for tests); ``auto`` (where a default must be picked): ``dfn`` when battlab's
#: physics factory is importable, else ``standin``
PHYSICS = ("dfn", "standin")
#: other spellings accepted (not listed in --help)
PHYSICS_ALIASES = {"stand-in": "standin", "stand_in": "standin", "ecm": "standin", "model": "dfn"}


class AliasChoice(click.Choice):
    """A choice that also takes hidden alternative spellings, mapped to the listed value."""

    def __init__(self, choices: Sequence[str], aliases: Mapping[str, str], case_sensitive: bool = False) -> None:
        super().__init__(list(choices), case_sensitive=case_sensitive)
        self.aliases = {k.lower(): v for k, v in aliases.items()}

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, str) and value.strip().lower() in self.aliases:
            value = self.aliases[value.strip().lower()]
        return super().convert(value, param, ctx)


def physics_option(*, auto: bool, default: str) -> Any:
    """``--physics``: ``dfn|standin``, with ``auto`` listed where the command picks by what is installed; ``auto``
    is accepted everywhere (where battlab's model is always there it means ``dfn``)."""
    listed = ("auto", *PHYSICS) if auto else PHYSICS
    aliases = dict(PHYSICS_ALIASES) if auto else {**PHYSICS_ALIASES, "auto": "dfn"}
    what = "dfn: battlab's DFN-thermal model; standin: the drivers' equivalent-circuit cell (fast, for tests)"
    if auto:
        what = f"auto: dfn if battlab's physics is available, else standin; {what}"
    return click.option(
        "--physics",
        type=AliasChoice(listed, aliases),
        default=default,
        show_default=True,
        help=f"Cell physics of the virtual tester. {what}.",
    )


def extension_option() -> Any:
    """``--extension KEY[:NAME=VALUE,...]`` (repeatable): switch a catalog model extension on."""
    from battlab.parameters import EXTENSIONS

    return click.option(
        "--extension",
        "extensions",
        multiple=True,
        metavar="KEY[:NAME=VALUE,...]",
        help="Switch a model extension on, its parameters [SI] at VALUE (the rest at their 'off' values); "
        f"repeatable. KEY: {', '.join(EXTENSIONS)}. E.g. contact_resistance:R_c=0.0015.",
    )


def apply_extensions(cell: Any, specs: Sequence[str], isothermal: bool = False) -> Any:
    """``cell`` with the ``--extension`` specs switched on; a bad spec or a contradiction with ``isothermal`` is
    one :class:`InputError` naming the option."""
    from battlab.model.extensions import ModelOptions

    for spec in specs:
        key, _, rest = spec.partition(":")
        values: dict[str, float] = {}
        for item in filter(None, (s.strip() for s in rest.split(","))):
            name, eq, text = item.partition("=")
            try:
                values[name.strip()] = float(text)
            except ValueError:
                raise InputError(
                    f"--extension {spec!r}: expected KEY[:NAME=VALUE,...] with numbers, e.g. "
                    "contact_resistance:R_c=0.0015"
                ) from None
            if not eq:
                raise InputError(f"--extension {spec!r}: {item!r} is not NAME=VALUE")
        try:
            cell = cell.with_extension(key.strip(), **values)
        except InputError as exc:
            raise InputError(f"--extension {spec!r}: {exc}") from None
    try:
        ModelOptions.of(cell, isothermal)
    except InputError as exc:
        raise InputError(f"--extension with --isothermal: {exc}") from None
    return cell


def ocp_option() -> Any:
    """``--ocp E=FILE`` (repeatable): an electrode's open-circuit potential from a half-cell CSV."""
    return click.option(
        "--ocp",
        "ocps",
        multiple=True,
        metavar="E=FILE",
        help="Replace electrode E's open-circuit potential (E: n or p) by a half-cell curve: a CSV of stoichiometry "
        "and potential vs Li/Li+ [V]; repeatable. E.g. p=nca_half_cell.csv.",
    )


def apply_ocps(cell: Any, specs: Sequence[str]) -> Any:
    """``cell`` with the ``--ocp`` curves; a bad spec or file is one :class:`InputError` naming the option."""
    from battlab.io.ocp import with_half_cell_ocp

    for spec in specs:
        electrode, eq, path = spec.partition("=")
        if not eq or electrode.strip() not in ("n", "p") or not path.strip():
            raise InputError(f"--ocp {spec!r}: expected E=FILE with E n or p, e.g. p=nca_half_cell.csv")
        try:
            cell = with_half_cell_ocp(cell, electrode.strip(), path.strip())
        except InputError as exc:
            raise InputError(f"--ocp {spec!r}: {exc}") from None
    return cell


#: the range of an options value's field that a command-line option sets (:func:`dataclass_options`), by name
FIELD_BOUNDS = {
    "soc0": SOC,
    "dt": DT,
    "max_iter": EVALUATIONS,
    "polish": Bounds("the number of evaluations", low=0.0),
    "widen": Bounds("the widening of the ranges", low=0.0, high=2.0),
    "rated_capacity": CAPACITY,
}


def dataclass_options(fields: Sequence[Any]) -> Any:
    """Click options made from dataclass fields whose metadata holds their help (``help``; optional ``flag``,
    ``metavar``, ``choices``, ``type`` "path", ``cli_default``): one declaration of each setting, in the options
    value the workflow takes. A boolean field is a flag; the option's default is the field's. A field named in
    :data:`FIELD_BOUNDS` is checked against its range, stated in the help, as the other commands' options are."""

    def decorate(fn: Any) -> Any:
        for f in reversed(list(fields)):
            meta = f.metadata
            flags = meta.get("flag") or (f"--{f.name.replace('_', '-')}",)
            default = meta.get("cli_default", f.default)
            kw: dict[str, Any] = {"help": meta["help"], "default": default}
            bounds = FIELD_BOUNDS.get(f.name)
            if bounds is not None:
                kw["help"] = f"{meta['help'].rstrip('.')}; {bounds.describe()}."
                kw["callback"] = _checked(flags[0], bounds)
            if meta.get("metavar"):
                kw["metavar"] = meta["metavar"]
            if isinstance(f.default, bool):
                kw["is_flag"] = True
            elif meta.get("choices"):
                kw["type"] = click.Choice(list(meta["choices"]))
                kw["show_default"] = True
            elif meta.get("type") == "path":
                kw["type"] = click.Path(dir_okay=False)
            elif isinstance(f.default, int | float) and f.default is not None:
                kw["type"] = type(f.default)
                kw["show_default"] = True
            elif f.type in ("float | None", "float"):
                kw["type"] = float
            fn = click.option(*flags, f.name, **kw)(fn)
        return fn

    return decorate


__all__ = [
    "AMBIENT_OPTION",
    "CAPACITY",
    "DATA_FORMATS",
    "DT",
    "FIELD_BOUNDS",
    "PHYSICS",
    "SOC",
    "TEMPERATURE",
    "VOLTAGE",
    "dataclass_options",
    "AliasChoice",
    "Bounds",
    "ambient_option",
    "apply_extensions",
    "apply_ocps",
    "bounded_option",
    "dt_option",
    "extension_option",
    "max_iter_option",
    "ocp_option",
    "parse_ambients",
    "parse_v_limits",
    "physics_option",
    "soc0_option",
    "v_limits_option",
]
