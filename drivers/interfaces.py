"""The two device interfaces the runner programs against: :class:`Cycler` and :class:`Chamber`.

Each is complete: the runner calls nothing else on an instrument. What differs between instruments is declared, not
probed: ``capabilities`` (:class:`CyclerCapabilities`, :class:`ChamberCapabilities`, frozen) says which optional
operations work; an optional operation the instrument lacks raises :class:`~drivers.errors.NotSupported` before any
I/O, and the runner asks the capabilities before calling it. :mod:`drivers.defaults` gives a driver the documented
behaviour of every optional operation it does not have.

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


@dataclass(frozen=True)
class InstrumentCapabilities:
    """What any instrument may have: ``link_timeout``: the link's read timeout (``link_timeout_s``) can be changed
    while connected."""

    link_timeout: bool = False


@dataclass(frozen=True)
class CyclerCapabilities(InstrumentCapabilities):
    """What a cycler has beyond the required operations (all False: a plain current source with read-back).

    ``clock``: :meth:`Cycler.clock` is the instrument's own clock (else the host's real clock times the run);
    ``timestamps``: :meth:`Cycler.measure` stamps each sample with that clock's time (``Measurement.t_s``);
    ``low_voltage_cutoff``: :meth:`Cycler.set_voltage_limits` takes a low limit (else the runner enforces it);
    ``temperature_limit``: :meth:`Cycler.set_temperature_limit` programs an over-temperature trip;
    ``watchdog``: :meth:`Cycler.set_watchdog` programs an I/O watchdog (output off when the host falls silent);
    ``clear_protection``: :meth:`Cycler.clear_protection` clears a latched protection remotely; and
    ``link_timeout`` (:class:`InstrumentCapabilities`).
    """

    clock: bool = False
    timestamps: bool = False
    low_voltage_cutoff: bool = False
    temperature_limit: bool = False
    watchdog: bool = False
    clear_protection: bool = False

    def __post_init__(self) -> None:
        if self.timestamps and not self.clock:
            raise ValueError("a cycler that stamps its samples has a clock: timestamps=True needs clock=True")


@dataclass(frozen=True)
class ChamberCapabilities(InstrumentCapabilities):
    """What a chamber has beyond the required operations: ``link_timeout`` (:class:`InstrumentCapabilities`)."""


@runtime_checkable
class Instrument(Protocol):
    """What the runner needs of any instrument: a name, its capabilities, its link's retries and timeout, identity,
    resync, close."""

    #: a short name for messages (e.g. ``cycler[socket://127.0.0.1:5025]``)
    name: str
    capabilities: InstrumentCapabilities
    #: the driver's own extra attempts for an exchange that failed on the link (0 without a link); settable
    retries: int

    @property
    def link_timeout_s(self) -> float | None:
        """The link's read timeout / s (None: no link, or a timeout fixed when it was opened)."""
        ...

    @link_timeout_s.setter
    def link_timeout_s(self, timeout_s: float) -> None:
        """Change the link's read timeout / s (NotSupported without the ``link_timeout`` capability)."""
        ...

    def identify(self) -> str:
        """The instrument's identity string (e.g. the ``*IDN?`` reply, or model and part number)."""
        ...

    def resync(self) -> None:
        """After an exchange failed: drop a late reply still on its way (reconnect or flush the link), so that the
        next exchange does not read it as its own. A no-op where the link resynchronises itself or there is none."""
        ...

    def close(self) -> None:
        """Release the connection (does not change the output or the set point)."""
        ...


@runtime_checkable
class Cycler(Instrument, Protocol):
    """A bidirectional current source with voltage read-back (a battery cycler channel)."""

    capabilities: CyclerCapabilities
    #: the time / s, on :meth:`clock`, at which the last :meth:`set_current` took effect, where the instrument says
    #: so in the same exchange; else None
    last_applied_t_s: float | None

    def clock(self) -> Clock:
        """The clock of this instrument's times: its own with the ``clock`` capability, else the host's
        :class:`~drivers.clock.RealClock`."""
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
        """Measure voltage, current and (if available) temperature, in one exchange if the instrument allows."""
        ...

    def set_voltage_limits(self, low_V: float | None, high_V: float) -> None:
        """Voltage window / V; the output must not be driven outside it. ``low_V`` None: the high limit only (a low
        limit needs the ``low_voltage_cutoff`` capability, else NotSupported)."""
        ...

    def set_current_limits(self, charge_A: float, discharge_A: float) -> None:
        """Largest charge and discharge current magnitudes / A that :meth:`set_current` accepts."""
        ...

    def set_temperature_limit(self, T_max_K: float) -> None:
        """Over-temperature trip / K: output off above it (``temperature_limit`` capability, else NotSupported)."""
        ...

    def protection(self) -> ProtectionState:
        """The latched protection state."""
        ...

    def clear_protection(self) -> None:
        """Clear latched protection; the output stays off until switched on again (``clear_protection``
        capability, else NotSupported)."""
        ...

    def errors(self) -> list[tuple[int, str]]:
        """Drain the instrument's error queue: ``[(code, message), ...]``, empty if none."""
        ...

    def set_watchdog(self, timeout_s: float | None) -> None:
        """Instrument-side watchdog: output off when the host is silent for ``timeout_s`` (None: disable;
        ``watchdog`` capability, else NotSupported)."""
        ...

    def safe_off(self) -> bool:
        """Best-effort output off that never raises; True if the instrument confirmed it."""
        ...

    def send_off(self) -> bool:
        """Output off for a link known to be dead: sent once without waiting for a confirmation, never raises; True
        if it was sent (an instrument without an unconfirmed write turns its output off as :meth:`safe_off` does)."""
        ...


@runtime_checkable
class Chamber(Instrument, Protocol):
    """A thermal chamber with one temperature loop."""

    capabilities: ChamberCapabilities

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
