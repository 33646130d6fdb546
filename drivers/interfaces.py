"""The two device interfaces the runner programs against: :class:`Cycler` and :class:`Chamber`.

Conventions (docs/conventions.md): SI units, time in s; **current positive = charge** (BDF); temperatures in K inside
``drivers`` except at the chamber interface, which speaks °C because chambers do (``set_point(T_degC)``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

from drivers.clock import Clock


@dataclass(frozen=True)
class Measurement:
    """One sample from a cycler.

    ``voltage_V``: terminal voltage / V; ``current_A``: measured current / A, positive = charge;
    ``temperature_K``: cell surface temperature / K, or None if the instrument has no probe;
    ``t_s``: the instrument's own time stamp / s, or None if it gives none (the runner stamps it).
    """

    voltage_V: float
    current_A: float
    temperature_K: float | None = None
    t_s: float | None = None


@dataclass(frozen=True)
class ProtectionState:
    """The latched protection state of a cycler output.

    ``tripped``: the output was turned off by a protection; ``causes``: short names such as ``"OV"``,
    ``"OT"``, ``"WDOG"``, ``"INH"``, ``"VLIM+"``; ``raw``: the instrument's status register value.
    """

    tripped: bool
    causes: frozenset[str] = field(default_factory=frozenset)
    raw: int = 0


@runtime_checkable
class Cycler(Protocol):
    """A bidirectional current source with voltage read-back (a battery cycler channel)."""

    name: str

    def identify(self) -> str:
        """The instrument's identity string (e.g. the ``*IDN?`` reply)."""
        ...

    def initialize(self) -> None:
        """Put the instrument in a known state: output off, current priority, status cleared."""
        ...

    def set_current(self, current_A: float) -> None:
        """Program the current / A, positive = charge. Raises InputError outside the configured limits."""
        ...

    def output(self, on: bool) -> None:
        """Switch the output on or off."""
        ...

    def measure(self) -> Measurement:
        """Measure voltage, current and (if available) temperature, in one exchange if the dialect allows."""
        ...

    def set_voltage_limits(self, low_V: float | None, high_V: float) -> None:
        """Voltage window / V; the output must not be driven outside it (``low_V`` None: not supported)."""
        ...

    def set_current_limits(self, charge_A: float, discharge_A: float) -> None:
        """Largest charge and discharge current magnitudes / A that :meth:`set_current` accepts."""
        ...

    def protection(self) -> ProtectionState:
        """The latched protection state."""
        ...

    def clear_protection(self) -> None:
        """Clear latched protection; the output stays off until switched on again."""
        ...

    def errors(self) -> list[tuple[int, str]]:
        """Drain the instrument's error queue: ``[(code, message), ...]``, empty if none."""
        ...

    def set_watchdog(self, timeout_s: float | None) -> None:
        """Instrument-side watchdog: output off when the host is silent for ``timeout_s`` (None: disable)."""
        ...

    def safe_off(self) -> bool:
        """Best-effort output off that never raises; True if the instrument confirmed it."""
        ...

    def close(self) -> None:
        """Release the connection (does not change the output)."""
        ...


@runtime_checkable
class Chamber(Protocol):
    """A thermal chamber with one temperature loop."""

    name: str

    def identify(self) -> str:
        """The controller's identity (model, part number)."""
        ...

    def set_point(self, T_degC: float) -> None:
        """Set the air temperature set point / °C and make sure the chamber is controlling."""
        ...

    def read(self) -> float:
        """Air temperature / °C. Raises InstrumentFault if the chamber reports an alarm."""
        ...

    def alarms(self) -> list[str]:
        """Active alarms (empty if none)."""
        ...

    def wait_stable(
        self, tol: float, timeout: float, clock: Clock, *, hold_s: float = 60.0, poll_s: float = 5.0
    ) -> float:
        """Wait until |T − set point| ≤ ``tol`` (K) for ``hold_s`` s; InstrumentFault after ``timeout`` s.

        Times are in ``clock``'s seconds. Returns the last reading / °C.
        """
        ...

    def close(self) -> None:
        """Release the connection."""
        ...
