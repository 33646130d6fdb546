"""The documented behaviour of every optional operation, for a driver that lacks it.

A driver class inherits :class:`CyclerDefaults` (or :class:`ChamberDefaults`) and implements the required operations
and the ones its ``capabilities`` declare; the rest behave as below. Nothing here does I/O. (A cycler without a
low-voltage cut-off raises NotSupported from its own ``set_voltage_limits`` when given a ``low_V``.)

=========================  ===========================================================================
``capabilities``           nothing optional (override with what the instrument has)
``retries``                0 (no link of its own to retry on)
``link_timeout_s``         None; setting it raises NotSupported
``resync()``               no-op (nothing to resynchronise)
``clock()``                the host's :class:`~drivers.clock.RealClock`
``last_applied_t_s``       None (the instrument does not say when a current took effect)
``set_temperature_limit``  NotSupported
``clear_protection``       NotSupported
``set_watchdog``           NotSupported
``send_off()``             :meth:`safe_off` (no unconfirmed write: the output is turned off as usual)
=========================  ===========================================================================
"""

from __future__ import annotations

from drivers.clock import Clock, RealClock
from drivers.errors import NotSupported
from drivers.interfaces import ChamberCapabilities, CyclerCapabilities, InstrumentCapabilities
from drivers.transport import TextAdapter


class _InstrumentDefaults:
    name: str
    retries: int = 0

    @property
    def link_timeout_s(self) -> float | None:
        return None

    @link_timeout_s.setter
    def link_timeout_s(self, timeout_s: float) -> None:
        raise NotSupported(self.name, "changing the link timeout", "no link timeout to change")

    def resync(self) -> None:
        """Nothing to resynchronise."""


class CyclerDefaults(_InstrumentDefaults):
    """A cycler's optional operations for a driver without them (module docstring)."""

    capabilities = CyclerCapabilities()
    last_applied_t_s: float | None = None

    def clock(self) -> Clock:
        return RealClock()

    def set_temperature_limit(self, T_max_K: float) -> None:
        raise NotSupported(self.name, "an over-temperature trip")

    def clear_protection(self) -> None:
        raise NotSupported(self.name, "clearing protection remotely")

    def set_watchdog(self, timeout_s: float | None) -> None:
        raise NotSupported(self.name, "an instrument watchdog")

    def send_off(self) -> bool:
        return self.safe_off()  # type: ignore[attr-defined]  # a required operation of every cycler


class ChamberDefaults(_InstrumentDefaults):
    """A chamber's optional operations for a driver without them."""

    capabilities = ChamberCapabilities()


class TextAdapterLink:
    """The link operations of a driver whose connection is a text adapter (``self.adapter``): ``resync`` is the
    adapter's ``recover``, and ``link_timeout_s`` its read timeout (changeable with the ``link_timeout``
    capability, which such a driver declares when its adapter has a timeout)."""

    name: str
    adapter: TextAdapter
    capabilities: InstrumentCapabilities

    def resync(self) -> None:
        self.adapter.recover()

    @property
    def link_timeout_s(self) -> float | None:
        return self.adapter.timeout_s

    @link_timeout_s.setter
    def link_timeout_s(self, timeout_s: float) -> None:
        if not self.capabilities.link_timeout:
            raise NotSupported(self.name, "changing the link timeout", f"adapter {self.adapter.name} has none")
        self.adapter.timeout_s = float(timeout_s)


__all__ = ["ChamberDefaults", "CyclerDefaults", "TextAdapterLink"]
