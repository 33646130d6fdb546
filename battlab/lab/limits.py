"""Limits: the instruments' (kept as TOML files), the cell's, and the safety envelope a run enforces.

An instrument limits file (``battlab run --limits bench.toml``)::

    [cycler]
    dialect = "keysight-n7951a"       # optional: the SCPI dialect (battlab run --dialect overrides it)
    voltage_min = 0.0                 # V: the range the channel may be programmed to
    voltage_max = 20.0                # V
    current_charge_max = 20.0         # A (magnitude)
    current_discharge_max = 2.0       # A (magnitude; a supply sinks less than it sources)
    [chamber]
    temperature_min = -40.0           # degC: set-point range
    temperature_max = 150.0           # degC
    safe_set_point = 25.0             # degC: where the chamber goes after an abort

Without ``--limits`` the built-in :data:`VIRTUAL_LIMITS` apply, and only to battlab's virtual tester; a real
instrument needs its file. The cell's limits come from the cell (``V_min``, ``V_max``, ``T_max``; the
current bound is 5C of ``Q_nom``, the input library's bound, as the cell has no current parameter).

:class:`Envelope` is what the runner enforces on every sample and programs into the instrument: the plan's
``[limits]`` (its abort band), checked by :mod:`battlab.lab.preflight` to lie within the cell's window
(± ``CELL_VOLTAGE_MARGIN_V``) and the instruments' ranges.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from protocols.errors import InputError

#: The plan's abort band may exceed the cell's voltage window by this much (CV holds at the window's edge).
CELL_VOLTAGE_MARGIN_V = 0.1
CELL_C_RATE_MAX = 5.0


@dataclass(frozen=True)
class CyclerLimits:
    """What a cycler channel may be programmed to (V, A magnitudes)."""

    voltage_min: float
    voltage_max: float
    current_charge_max: float
    current_discharge_max: float
    dialect: str | None = None


@dataclass(frozen=True)
class ChamberLimits:
    """A chamber's set-point range and its safe set point (degC)."""

    temperature_min: float
    temperature_max: float
    safe_set_point: float = 25.0


@dataclass(frozen=True)
class InstrumentLimits:
    """Both instruments' limits and where they came from (a file path or ``built-in: …``)."""

    cycler: CyclerLimits
    chamber: ChamberLimits
    source: str

    def to_dict(self) -> dict[str, Any]:
        cyc = {k: v for k, v in asdict(self.cycler).items() if v is not None}
        return {"cycler": cyc, "chamber": asdict(self.chamber), "source": self.source}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], source: str) -> InstrumentLimits:
        """Read the file form; errors name ``source``, the table and the field."""
        if not isinstance(data, Mapping):
            raise InputError(f"{source}: expected tables [cycler] and [chamber]")
        unknown = [k for k in data if k not in ("cycler", "chamber", "source")]
        if unknown:
            raise InputError(f"{source}: unknown table(s) {unknown}; expected [cycler] and [chamber]")
        cyc = _table(data, "cycler", source)
        cha = _table(data, "chamber", source)
        _fields(cyc, CyclerLimits, source, "cycler")
        _fields(cha, ChamberLimits, source, "chamber")
        dialect = cyc.get("dialect")
        if dialect is not None and not isinstance(dialect, str):
            raise InputError(f"{source}: [cycler] dialect must be a string, got {dialect!r}")
        cycler = CyclerLimits(
            _num(cyc, "voltage_min", source, "cycler", "V", minimum=0.0),
            _num(cyc, "voltage_max", source, "cycler", "V", minimum=0.0),
            _num(cyc, "current_charge_max", source, "cycler", "A", minimum=0.0),
            _num(cyc, "current_discharge_max", source, "cycler", "A", minimum=0.0),
            dialect,
        )
        if cycler.voltage_min >= cycler.voltage_max:
            raise InputError(f"{source}: [cycler] voltage_min must be below voltage_max")
        chamber = ChamberLimits(
            _num(cha, "temperature_min", source, "chamber", "degC"),
            _num(cha, "temperature_max", source, "chamber", "degC"),
            _num(cha, "safe_set_point", source, "chamber", "degC", default=25.0),
        )
        if not chamber.temperature_min <= chamber.safe_set_point <= chamber.temperature_max:
            raise InputError(
                f"{source}: [chamber] safe_set_point {chamber.safe_set_point:g} degC is outside "
                f"[{chamber.temperature_min:g}, {chamber.temperature_max:g}] degC"
            )
        return cls(cycler, chamber, source)

    @classmethod
    def load(cls, path: str | Path) -> InstrumentLimits:
        """Read an instrument limits TOML file."""
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: no such limits file")
        try:
            data = tomllib.loads(path.read_text(encoding="utf-8"))
        except tomllib.TOMLDecodeError as exc:
            raise InputError(f"{path}: not valid TOML ({exc})") from None
        return cls.from_dict(data, str(path))


#: The virtual tester's instruments (battlab-virtual dialect: 0–10 V, ±20 A; F4T loop −40…150 °C).
VIRTUAL_LIMITS = InstrumentLimits(
    CyclerLimits(0.0, 10.0, 20.0, 20.0, dialect="battlab-virtual"),
    ChamberLimits(-40.0, 150.0, 25.0),
    "built-in: battlab virtual tester",
)


@dataclass(frozen=True)
class CellWindow:
    """The cell's safe operating window: V, A (magnitude), K."""

    name: str
    voltage_min: float
    voltage_max: float
    current_max: float
    temperature_max_K: float
    capacity_Ah: float

    @classmethod
    def of(cls, cell: Any) -> CellWindow:
        """From a :class:`battlab.Cell` (``V_min``, ``V_max``, ``T_max``, ``Q_nom``)."""
        q = float(cell["Q_nom"])
        return cls(cell.name, float(cell["V_min"]), float(cell["V_max"]), CELL_C_RATE_MAX * q, float(cell["T_max"]), q)


@dataclass(frozen=True)
class Envelope:
    """What the runner enforces: voltage band (V), current magnitudes (A), surface temperature (K)."""

    voltage_min: float
    voltage_max: float
    current_charge_max: float
    current_discharge_max: float
    temperature_max_K: float

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


def _table(data: Mapping[str, Any], name: str, source: str) -> Mapping[str, Any]:
    table = data.get(name)
    if not isinstance(table, Mapping):
        raise InputError(f"{source}: missing table [{name}]")
    return table


def _fields(table: Mapping[str, Any], kind: type, source: str, name: str) -> None:
    allowed = set(kind.__dataclass_fields__)  # type: ignore[attr-defined]
    unknown = sorted(k for k in table if k not in allowed)
    if unknown:
        raise InputError(f"{source}: [{name}] unknown field(s) {unknown}; allowed: {', '.join(sorted(allowed))}")


def _num(
    table: Mapping[str, Any],
    key: str,
    source: str,
    name: str,
    unit: str,
    *,
    minimum: float | None = None,
    default: float | None = None,
) -> float:
    if key not in table:
        if default is not None:
            return default
        raise InputError(f"{source}: [{name}] missing field {key!r} [{unit}]")
    v = table[key]
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
        raise InputError(f"{source}: [{name}] {key} must be a number [{unit}], got {v!r}")
    if minimum is not None and v < minimum:
        raise InputError(f"{source}: [{name}] {key} must be >= {minimum:g} {unit}, got {v!r}")
    return float(v)


__all__ = [
    "CELL_C_RATE_MAX",
    "CELL_VOLTAGE_MARGIN_V",
    "CellWindow",
    "ChamberLimits",
    "CyclerLimits",
    "Envelope",
    "InstrumentLimits",
    "VIRTUAL_LIMITS",
]
