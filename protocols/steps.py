"""Protocol steps, end conditions and safety limits (positive current = charge, SI units).

The steps a :class:`~protocols.protocol.Protocol` is made of; see that module for the file format.
"""

from __future__ import annotations

import difflib
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum
from typing import Any, ClassVar

from protocols.constants import ONE_C_A
from protocols.directions import Direction
from protocols.errors import InputError
from protocols.profile import Profile


def did_you_mean(word: str, options: Sequence[str]) -> str:
    """' (did you mean X?)' for the closest of ``options`` to a mistyped ``word``, else ''."""
    close = difflib.get_close_matches(word, list(options), n=1)
    return f" (did you mean {close[0]!r}?)" if close else ""


class Quantity(Enum):
    """What an end condition compares."""

    TIME = "time"
    VOLTAGE = "voltage"
    CURRENT = "current"
    CAPACITY = "capacity"

    @property
    def unit(self) -> str:
        """SI unit of the compared value."""
        return {"time": "s", "voltage": "V", "current": "A", "capacity": "Ah"}[self.value]


class Comparison(Enum):
    """Comparison operator of an end condition."""

    GE = ">="
    LE = "<="


_END_RE = re.compile(r"^\s*([a-z]+)\s*(>=|<=|>|<|=)\s*([-+0-9.eE]+)\s*([A-Za-z]*)\s*$")


@dataclass(frozen=True)
class EndCondition:
    """``quantity op value``; for current the magnitude |I| is compared."""

    quantity: Quantity
    op: Comparison
    value: float

    def __post_init__(self) -> None:
        v = float(self.value)
        object.__setattr__(self, "value", v)
        if not math.isfinite(v):
            raise InputError(f"end condition {self.quantity.value}: value must be finite, got {v}")
        if self.quantity in (Quantity.TIME, Quantity.CAPACITY):
            if self.op is not Comparison.GE:
                raise InputError(f"end condition on {self.quantity.value} must use '>=', got '{self.op.value}'")
            if v <= 0:
                raise InputError(f"end condition {self.quantity.value} >= {v:g}: value must be positive")
        elif v < 0:
            raise InputError(f"end condition {self.quantity.value} {self.op.value} {v:g}: must not be negative")

    def __str__(self) -> str:
        v = self.value
        text = str(int(v)) if v.is_integer() and abs(v) < 1e15 else repr(v)
        return f"{self.quantity.value} {self.op.value} {text}"

    @classmethod
    def parse(cls, text: str) -> EndCondition:
        """Parse ``"voltage <= 2.5"`` (an optional unit suffix must be the SI one: s, V, A, Ah)."""
        if isinstance(text, EndCondition):
            return text
        if not isinstance(text, str):
            raise InputError(f"end condition must be a string like 'time >= 60', got {text!r}")
        m = _END_RE.match(text)
        if not m:
            raise InputError(f"cannot read end condition {text!r}; expected e.g. 'voltage <= 2.5'")
        name, op, value, unit = m.groups()
        try:
            q = Quantity(name)
        except ValueError:
            hint = did_you_mean(name, [q.value for q in Quantity])
            raise InputError(f"end condition {text!r}: unknown quantity {name!r}{hint}") from None
        if op not in (">=", "<="):
            raise InputError(f"end condition {text!r}: use '>=' or '<=', not '{op}'")
        if unit and unit != q.unit:
            raise InputError(f"end condition {text!r}: {q.value} is in {q.unit}, not {unit}")
        try:
            v = float(value)
        except ValueError:
            raise InputError(f"end condition {text!r}: {value!r} is not a number") from None
        return cls(q, Comparison(op), v)


def after(seconds: float) -> EndCondition:
    """End after ``seconds`` of step time."""
    return EndCondition(Quantity.TIME, Comparison.GE, seconds)


def voltage_above(volts: float) -> EndCondition:
    """End when V >= ``volts``."""
    return EndCondition(Quantity.VOLTAGE, Comparison.GE, volts)


def voltage_below(volts: float) -> EndCondition:
    """End when V <= ``volts``."""
    return EndCondition(Quantity.VOLTAGE, Comparison.LE, volts)


def current_below(amps: float) -> EndCondition:
    """End when |I| <= ``amps`` (CV taper)."""
    return EndCondition(Quantity.CURRENT, Comparison.LE, amps)


def capacity_reached(amp_hours: float) -> EndCondition:
    """End when the step has moved ``amp_hours`` [Ah] (either direction)."""
    return EndCondition(Quantity.CAPACITY, Comparison.GE, amp_hours)


@dataclass(frozen=True)
class SafetyLimits:
    """Abort limits for the whole test (V, A magnitude, K)."""

    voltage_min: float = 2.45
    voltage_max: float = 4.25
    current_max: float = 5.0 * ONE_C_A
    temperature_max: float = 323.15

    def __post_init__(self) -> None:
        for name in ("voltage_min", "voltage_max", "current_max", "temperature_max"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v <= 0:
                raise InputError(f"limits: {name} must be a positive number, got {v!r}")
            object.__setattr__(self, name, float(v))
        if self.voltage_min >= self.voltage_max:
            raise InputError(
                f"limits: voltage_min ({self.voltage_min} V) must be below voltage_max ({self.voltage_max} V)"
            )


class StepKind(Enum):
    """Step types, as written in files."""

    REST = "rest"
    CC = "cc"
    CV = "cv"
    CCCV = "cccv"
    PROFILE = "profile"


def _ends(value: Any, allowed: tuple[Quantity, ...], kind: StepKind) -> tuple[EndCondition, ...]:
    if isinstance(value, str | EndCondition):
        value = (value,)
    ends = tuple(EndCondition.parse(v) for v in value)
    for e in ends:
        if e.quantity not in allowed:
            names = ", ".join(q.value for q in allowed) or "none"
            raise InputError(f"a {kind.value} step cannot end on {e.quantity.value} (allowed: {names})")
    return ends


def number(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise InputError(f"{what} must be a finite number, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class Rest:
    """Zero current until an end condition."""

    ends: tuple[EndCondition, ...]
    label: str = ""
    kind: ClassVar[StepKind] = StepKind.REST
    allowed: ClassVar[tuple[Quantity, ...]] = (Quantity.TIME, Quantity.VOLTAGE)

    def __post_init__(self) -> None:
        object.__setattr__(self, "ends", _ends(self.ends, self.allowed, self.kind))
        if not self.ends:
            raise InputError("a rest step needs an end condition (e.g. 'time >= 3600')")


@dataclass(frozen=True)
class ConstantCurrent:
    """Constant current [A] (positive = charge) until an end condition."""

    current: float
    ends: tuple[EndCondition, ...]
    label: str = ""
    kind: ClassVar[StepKind] = StepKind.CC
    allowed: ClassVar[tuple[Quantity, ...]] = (Quantity.TIME, Quantity.VOLTAGE, Quantity.CAPACITY)

    def __post_init__(self) -> None:
        object.__setattr__(self, "current", number(self.current, "cc step: current"))
        object.__setattr__(self, "ends", _ends(self.ends, self.allowed, self.kind))
        if self.current == 0:
            raise InputError("cc step: current is zero; use a rest step")
        if not self.ends:
            raise InputError("a cc step needs an end condition (time, voltage or capacity)")


@dataclass(frozen=True)
class ConstantVoltage:
    """Constant voltage [V] until an end condition (only the safety current limits |I|; for a CV with its own
    current limit use :class:`CCCV`, which is the same thing).

    ``direction`` (charge or discharge) is the current direction the step is programmed as (cyclers program
    CV as a charge or a discharge step).
    """

    voltage: float
    ends: tuple[EndCondition, ...]
    direction: Direction = Direction.CHARGE
    label: str = ""
    kind: ClassVar[StepKind] = StepKind.CV
    allowed: ClassVar[tuple[Quantity, ...]] = (Quantity.TIME, Quantity.CURRENT, Quantity.CAPACITY)

    def __post_init__(self) -> None:
        object.__setattr__(self, "voltage", number(self.voltage, "cv step: voltage"))
        if isinstance(self.direction, str):
            try:
                object.__setattr__(self, "direction", Direction(self.direction))
            except ValueError:
                raise InputError(
                    f"cv step: direction must be 'charge' or 'discharge', got {self.direction!r}"
                ) from None
        if self.direction is Direction.BOTH:
            raise InputError("cv step: direction must be 'charge' or 'discharge', not 'both'")
        object.__setattr__(self, "ends", _ends(self.ends, self.allowed, self.kind))
        if not self.ends:
            raise InputError("a cv step needs an end condition (time, current or capacity)")


@dataclass(frozen=True)
class CCCV:
    """Constant current [A] until ``voltage`` [V], then hold that voltage until an end condition."""

    current: float
    voltage: float
    ends: tuple[EndCondition, ...]
    label: str = ""
    kind: ClassVar[StepKind] = StepKind.CCCV
    allowed: ClassVar[tuple[Quantity, ...]] = (Quantity.TIME, Quantity.CURRENT, Quantity.CAPACITY)

    def __post_init__(self) -> None:
        object.__setattr__(self, "current", number(self.current, "cccv step: current"))
        object.__setattr__(self, "voltage", number(self.voltage, "cccv step: voltage"))
        object.__setattr__(self, "ends", _ends(self.ends, self.allowed, self.kind))
        if self.current == 0:
            raise InputError("cccv step: current is zero")
        if not self.ends:
            raise InputError("a cccv step needs an end condition (e.g. 'current <= 0.054')")


@dataclass(frozen=True)
class ProfileStep:
    """A sampled current profile, played once to its end (zero-order hold); only safety limits stop it."""

    profile: Profile
    label: str = ""
    kind: ClassVar[StepKind] = StepKind.PROFILE
    ends: ClassVar[tuple[EndCondition, ...]] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.profile, Profile):
            raise InputError(f"profile step needs a Profile, got {type(self.profile).__name__}")


Step = Rest | ConstantCurrent | ConstantVoltage | CCCV | ProfileStep


def step_duration(step: Step) -> float | None:
    """The step's duration [s] if a time end is its only way to end (else None)."""
    if isinstance(step, ProfileStep):
        return step.profile.duration
    if len(step.ends) == 1 and step.ends[0].quantity is Quantity.TIME:
        return step.ends[0].value
    return None
