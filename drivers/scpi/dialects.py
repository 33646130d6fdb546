"""SCPI dialects as data: one frozen profile per instrument family, a declarative table of properties.

Each :class:`ScpiProperty` is a row in pymeasure's style (command, validator, conversion, docstring). The
client driver (:mod:`drivers.scpi.cycler`) and the virtual instrument's server
(:mod:`drivers.virtual.cycler_server`) read the same table, so the virtual tester serves exactly the
dialect the driver speaks.

Where each command comes from (``source`` of each row):

- ``checked``: the command name and semantics were checked against the Keysight N6900/N7900 Advanced Power
  System *Operating and Service Guide* (SCPI reference: ``OUTPut:PROTection:WDOG[:STATe]``,
  ``OUTPut:PROTection:WDOG:DELay`` 1–3600 s in 1 s steps, current-priority mode with a positive voltage
  limit, ``[SOURce:]LIST:CURRent`` accepting negative values) or the same family's N6700C / N8700 guides
  (``OUTPut:PROTection:CLEar``, ``[SOURce:]VOLTage:PROTection[:LEVel]``), or the generic SCPI-99 /
  IEEE 488.2 commands every Keysight supply implements (``*IDN?``, ``*CLS``, ``SYSTem:ERRor?``,
  ``OUTPut[:STATe]``, ``[SOURce:]CURRent[:LEVel][:IMMediate][:AMPlitude]``).
- ``assumption``: the spelling follows the Keysight N6700/N6900 naming pattern but was not seen in a
  retrieved page of the N7900 manual (``[SOURce:]FUNCtion``, ``VOLTage:LIMit``, ``CURRent:LIMit[:NEGative]``,
  ``MEASure[:SCALar]:…``, the bit layout of ``STATus:QUEStionable:CONDition?``).
- ``extension``: battlab's virtual tester only (cell temperature probe, virtual clock, low-voltage cutoff,
  over-temperature trip). A real bench reads cell temperature through a separate logger.

The ITECH IT6000 profile is **entirely unverified** (no programming guide was retrievable): it is marked
``verified=False`` and the driver logs a warning when it is used.

Current sign: battlab's current is positive on charge. A supply whose + terminal is wired to the cell's +
terminal *sources* (positive output current) when it charges the cell, so ``current_sign = +1``. A
regenerative supply that reports sinking as positive, or a reversed wiring, sets ``current_sign = -1``;
the driver applies this sign in exactly one place (:meth:`ScpiCycler._to_instrument`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, Literal

from protocols.errors import InputError

Kind = Literal["float", "int", "bool", "str"]


# -- validators (pymeasure style: validator(value, values) -> value to send, or raise InputError) ----------
def strict_range(value: float, values: tuple[float, float]) -> float:
    """Accept ``values[0] <= value <= values[1]``."""
    lo, hi = values
    if not (isinstance(value, int | float) and math.isfinite(value)) or not lo <= value <= hi:
        raise InputError(f"value {value!r} is outside the instrument's range [{lo:g}, {hi:g}]")
    return float(value)


def integer_ceil_range(value: float, values: tuple[float, float]) -> int:
    """Round up to a whole number, then accept it within ``values`` (e.g. watchdog seconds)."""
    if not (isinstance(value, int | float) and math.isfinite(value)):
        raise InputError(f"value {value!r} is not a number")
    return int(strict_range(math.ceil(value - 1e-9), values))


def strict_discrete_set(value: Any, values: tuple[Any, ...]) -> Any:
    """Accept one of ``values``."""
    if value not in values:
        raise InputError(f"value {value!r} is not one of {values}")
    return value


def boolean(value: Any, values: Any = None) -> bool:
    if not isinstance(value, bool):
        raise InputError(f"value {value!r} is not a boolean")
    return value


def _identity(x: Any) -> Any:
    return x


def _c_to_k(x: float) -> float:
    return x + 273.15


def _k_to_c(x: float) -> float:
    return x - 273.15


@dataclass(frozen=True)
class ScpiProperty:
    """One row of a dialect's property table.

    ``header``: SCPI header pattern (see :mod:`drivers.scpi.codec`); ``kind``: value type on the wire;
    ``unit``: the instrument's unit; ``to_instrument``/``from_instrument``: conversions between battlab's
    units and the wire (e.g. K ↔ °C); ``values``/``validator``: what the instrument accepts, in *its*
    units (the client validates after ``to_instrument``; the virtual instrument checks the same range);
    ``source``: ``checked``, ``assumption`` or ``extension`` (module docstring).
    """

    name: str
    header: str
    kind: Kind
    doc: str
    unit: str = ""
    settable: bool = True
    queryable: bool = True
    values: Any = None
    validator: Callable[[Any, Any], Any] | None = None
    to_instrument: Callable[[Any], Any] = _identity
    from_instrument: Callable[[Any], Any] = _identity
    source: str = "assumption"
    digits: int = 6


@dataclass(frozen=True)
class ScpiDialect:
    """An instrument family's SCPI profile (pure data)."""

    name: str
    description: str
    properties: tuple[ScpiProperty, ...]
    #: properties read by :meth:`Cycler.measure`, in this order, in one compound query if ``compound``
    measure: tuple[str, ...] = ("voltage", "current_measured")
    compound: bool = True
    #: append ``;:SYST:ERR?`` to every setting: one round trip both confirms delivery and checks errors
    check_errors_inline: bool = True
    identity_query: str = "*IDN"
    error_query: str = "SYSTem:ERRor[:NEXT]"
    clear_status: str = "*CLS"
    protection_clear: str | None = "OUTPut:PROTection:CLEar"
    #: value written to the ``function`` property to select current priority (None: no such mode)
    priority_current: str | None = "CURR"
    #: ``STATus:QUEStionable:CONDition?`` bits → short cause names; ``trip_bits`` latch the output off
    status_bits: tuple[tuple[int, str], ...] = ()
    trip_bits: frozenset[int] = frozenset()
    current_sign: int = 1
    write_terminator: str = "\n"
    read_terminator: str = "\n"
    #: identity the virtual instrument reports when it serves this dialect
    sim_identity: str = "battlab,VirtualCycler,SIM0001,0.1"
    verified: bool = True
    _index: dict[str, ScpiProperty] = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        names = [p.name for p in self.properties]
        if len(set(names)) != len(names):
            raise ValueError(f"dialect {self.name}: duplicate property names")
        if self.current_sign not in (1, -1):
            raise ValueError(f"dialect {self.name}: current_sign must be +1 or -1")
        self._index.update({p.name: p for p in self.properties})
        missing = [m for m in self.measure if m not in self._index]
        if missing:
            raise ValueError(f"dialect {self.name}: measure names unknown properties {missing}")

    def has(self, name: str) -> bool:
        return name in self._index

    def prop(self, name: str) -> ScpiProperty:
        try:
            return self._index[name]
        except KeyError:
            raise InputError(
                f"instrument dialect {self.name} has no property {name!r} (it has {sorted(self._index)})"
            ) from None

    def status_names(self, raw: int) -> frozenset[str]:
        return frozenset(name for bit, name in self.status_bits if raw >> bit & 1)

    def tripped(self, raw: int) -> bool:
        return any(raw >> bit & 1 for bit in self.trip_bits)


# -- the property rows ---------------------------------------------------------------------------------------
def _core_properties(v_max: float, i_max: float, i_sink_max: float) -> tuple[ScpiProperty, ...]:
    return (
        ScpiProperty(
            "function",
            "[SOURce:]FUNCtion",
            "str",
            "Regulation priority: CURR or VOLT.",
            values=("CURR", "VOLT"),
            validator=strict_discrete_set,
            queryable=True,
            source="assumption (priority modes documented in the N6900/N7900 guide)",
        ),
        ScpiProperty(
            "current",
            "[SOURce:]CURRent[:LEVel][:IMMediate][:AMPlitude]",
            "float",
            "Programmed output current (instrument sign).",
            unit="A",
            values=(-i_sink_max, i_max),
            validator=strict_range,
            source="checked",
        ),
        ScpiProperty(
            "voltage_limit",
            "[SOURce:]VOLTage:LIMit[:POSitive]",
            "float",
            "Voltage limit in current priority (charge side).",
            unit="V",
            values=(0.0, v_max),
            validator=strict_range,
            source="assumption (current-priority voltage limit documented in the N6900/N7900 guide)",
        ),
        ScpiProperty(
            "current_limit",
            "[SOURce:]CURRent:LIMit[:POSitive]",
            "float",
            "Positive current limit.",
            unit="A",
            values=(0.0, i_max),
            validator=strict_range,
        ),
        ScpiProperty(
            "current_limit_neg",
            "[SOURce:]CURRent:LIMit:NEGative",
            "float",
            "Negative current limit (a negative number).",
            unit="A",
            values=(-i_sink_max, 0.0),
            validator=strict_range,
        ),
        ScpiProperty(
            "ovp",
            "[SOURce:]VOLTage:PROTection[:LEVel]",
            "float",
            "Over-voltage protection trip level.",
            unit="V",
            values=(0.0, 1.2 * v_max),
            validator=strict_range,
            source="checked (N8700/N6900 guides)",
        ),
        ScpiProperty("output", "OUTPut[:STATe]", "bool", "Output on/off.", validator=boolean, source="checked"),
        ScpiProperty(
            "watchdog_enabled",
            "OUTPut:PROTection:WDOG[:STATe]",
            "bool",
            "I/O watchdog: output off after WDOG:DELay s without SCPI I/O.",
            validator=boolean,
            source="checked (N6900/N7900 guide, OUTPut:PROTection:WDOG)",
        ),
        ScpiProperty(
            "watchdog_delay",
            "OUTPut:PROTection:WDOG:DELay",
            "int",
            "Watchdog delay, whole seconds 1–3600.",
            unit="s",
            values=(1, 3600),
            validator=integer_ceil_range,
            source="checked (N6900/N7900 guide)",
        ),
        ScpiProperty(
            "questionable",
            "STATus:QUEStionable:CONDition",
            "int",
            "Questionable-status condition register.",
            settable=False,
            source="assumption (bit layout)",
        ),
        ScpiProperty(
            "voltage",
            "MEASure[:SCALar]:VOLTage[:DC]",
            "float",
            "Measured output voltage.",
            unit="V",
            settable=False,
            source="assumption (MEASure:VOLTage? checked on E36xx)",
        ),
        ScpiProperty(
            "current_measured",
            "MEASure[:SCALar]:CURRent[:DC]",
            "float",
            "Measured output current (instrument sign).",
            unit="A",
            settable=False,
            source="assumption (MEASure:CURRent? checked on E36xx)",
        ),
    )


def _virtual_extensions() -> tuple[ScpiProperty, ...]:
    return (
        ScpiProperty(
            "voltage_limit_low",
            "[SOURce:]VOLTage:LIMit:LOW",
            "float",
            "Discharge cutoff: output off below this voltage.",
            unit="V",
            values=(0.0, 100.0),
            validator=strict_range,
            source="extension",
        ),
        ScpiProperty(
            "temperature",
            "MEASure[:SCALar]:TEMPerature",
            "float",
            "Cell surface temperature probe (°C on the wire, K in battlab).",
            unit="degC",
            settable=False,
            from_instrument=_c_to_k,
            source="extension",
            digits=4,
        ),
        ScpiProperty(
            "temperature_protection",
            "VIRTual:TEMPerature:PROTection",
            "float",
            "Over-temperature trip level (°C on the wire, K in battlab).",
            unit="degC",
            values=(-20.0, 130.0),
            validator=strict_range,
            to_instrument=_k_to_c,
            from_instrument=_c_to_k,
            source="extension",
        ),
        ScpiProperty(
            "time",
            "VIRTual:TIME",
            "float",
            "The virtual instrument's clock.",
            unit="s",
            settable=False,
            source="extension",
            digits=9,
        ),
        ScpiProperty(
            "speed",
            "VIRTual:SPEed",
            "float",
            "Virtual seconds per real second.",
            settable=False,
            source="extension",
        ),
    )


# Keysight N6900/N7900 questionable status register (as in the N6700 family): 0 OV, 1 OC, 2 PF, 3 CP+,
# 4 OT, 5 CP-, 6 OV-, 7 LIM+, 8 LIM-, 9 INH, 10 UNR, 11 PROT, 12 OSC — an assumption for the N7900.
_KEYSIGHT_BITS = (
    (0, "OV"),
    (1, "OC"),
    (2, "PF"),
    (3, "CP+"),
    (4, "OT"),
    (5, "CP-"),
    (6, "OV-"),
    (7, "LIM+"),
    (8, "LIM-"),
    (9, "INH"),
    (10, "UNR"),
    (11, "PROT"),
    (12, "OSC"),
)
_KEYSIGHT_TRIPS = frozenset({0, 1, 2, 4, 6, 9, 11})


def keysight_n7900(
    model: str = "N7951A", v_max: float = 50.0, i_max: float = 20.0, i_sink_max: float | None = None
) -> ScpiDialect:
    """Keysight N7900 APS family; ``i_sink_max`` defaults to 10 % of rating (102 % with an N7909A)."""
    sink = 0.102 * i_max if i_sink_max is None else i_sink_max
    return ScpiDialect(
        name=f"keysight-{model.lower()}",
        description=f"Keysight {model} (N6900/N7900 Advanced Power System), current priority",
        properties=_core_properties(v_max, i_max, sink),
        measure=("voltage", "current_measured"),
        status_bits=_KEYSIGHT_BITS,
        trip_bits=_KEYSIGHT_TRIPS,
        sim_identity=f"Keysight Technologies,{model},SIM0001,virtual",
    )


def itech_it6000(model: str = "IT6012C-80-300", v_max: float = 80.0, i_max: float = 300.0) -> ScpiDialect:
    """ITECH IT6000C regenerative supply: **unverified**, same SCPI naming assumed; no watchdog."""
    props = tuple(p for p in _core_properties(v_max, i_max, i_max) if not p.name.startswith("watchdog"))
    props = tuple(replace(p, source="assumption (IT6000 manual not checked)") for p in props)
    return ScpiDialect(
        name=f"itech-{model.lower()}",
        description=f"ITECH {model} bidirectional supply (unverified profile)",
        properties=props,
        measure=("voltage", "current_measured"),
        status_bits=_KEYSIGHT_BITS,
        trip_bits=_KEYSIGHT_TRIPS,
        sim_identity=f"ITECH Ltd.,{model},SIM0001,virtual",
        verified=False,
    )


def battlab_virtual(v_max: float = 10.0, i_max: float = 20.0) -> ScpiDialect:
    """The virtual tester's dialect: the N7900 family plus battlab's extensions (temperature, clock, cutoffs).

    ``measure`` reads voltage, current, temperature and the instrument's time in one compound query.
    """
    bits = _KEYSIGHT_BITS + ((13, "VLIM-"), (14, "WDOG"), (15, "MODEL"))
    return ScpiDialect(
        name="battlab-virtual",
        description="battlab virtual cycler (Keysight N7900-like, with extensions)",
        properties=_core_properties(v_max, i_max, i_max) + _virtual_extensions(),
        measure=("voltage", "current_measured", "temperature", "time"),
        status_bits=bits,
        trip_bits=frozenset({0, 1, 4, 7, 9, 11, 13, 14, 15}),
        sim_identity="battlab,Virtual Cycler VC-1,SIM0001,0.1",
    )


KEYSIGHT_N7900 = keysight_n7900()
ITECH_IT6000 = itech_it6000()
BATTLAB_VIRTUAL = battlab_virtual()
DIALECTS: dict[str, ScpiDialect] = {d.name: d for d in (KEYSIGHT_N7900, ITECH_IT6000, BATTLAB_VIRTUAL)}


def dialect_by_name(name: str) -> ScpiDialect:
    try:
        return DIALECTS[name]
    except KeyError:
        raise InputError(f"unknown SCPI dialect {name!r}; known: {sorted(DIALECTS)}") from None
