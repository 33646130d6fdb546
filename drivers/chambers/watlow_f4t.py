"""Watlow F4T controller (control loop ``loop``) over Modbus TCP or RTU: a :class:`Chamber`."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from drivers.chambers import watlow_codec as wc
from drivers.chambers.base import wait_stable
from drivers.clock import Clock
from drivers.defaults import ChamberDefaults
from drivers.errors import InstrumentFault, ReplyError
from drivers.registry import CHAMBER, UrlScheme, register
from drivers.urls import InstrumentURL, parse_url
from protocols.errors import InputError

if TYPE_CHECKING:
    from drivers.chambers.modbus import RegisterAdapter

#: Modbus TCP, Modbus RTU on a serial port, and RTU framing over a TCP socket (a serial-to-Ethernet gateway)
MODBUS_TCP = UrlScheme("modbus-tcp", options=frozenset({"unit", "timeout"}), default_port=502)
MODBUS_RTU = UrlScheme(
    "modbus-rtu", options=frozenset({"unit", "baud", "parity", "stopbits", "timeout"}), network=False, device=True
)
MODBUS_RTU_SOCKET = UrlScheme("modbus-rtu+socket", options=frozenset({"unit", "timeout"}))


class WatlowF4T(ChamberDefaults):
    """F4T temperature loop. Temperatures over Modbus follow the display units (register 1328), read once.

    The link's timeout is fixed when it is opened, and the register adapter resynchronises after every failed
    transaction itself (:class:`~drivers.defaults.ChamberDefaults`: no ``link_timeout`` capability, ``resync`` a
    no-op)."""

    def __init__(
        self,
        registers: RegisterAdapter,
        *,
        loop: int = 1,
        name: str | None = None,
        alarms: tuple[int, ...] = (1,),
    ) -> None:
        self.registers = registers
        self.loop = loop
        self.name = name or f"chamber[{registers.name}]"
        self.alarm_numbers = alarms
        self._units: int | None = None
        self._range_C: tuple[float, float] | None = None
        self._set_point_C: float | None = None

    @classmethod
    def open(
        cls,
        url: str | InstrumentURL,
        *,
        loop: int = 1,
        timeout_s: float | None = None,
        retries: int = 2,
        name: str | None = None,
    ) -> WatlowF4T:
        parsed = url if isinstance(url, InstrumentURL) else parse_url(url)
        if parsed.scheme not in ("modbus-tcp", "modbus-rtu", "modbus-rtu+socket"):
            raise InputError(
                f"chamber URL {parsed.raw!r}: a Watlow F4T needs modbus-tcp://, modbus-rtu:// or modbus-rtu+socket://"
            )
        from drivers.chambers.modbus import PymodbusRegisters  # pymodbus is imported when a Modbus link is opened

        regs = PymodbusRegisters.from_url(parsed, name=name or parsed.raw, timeout_s=timeout_s, retries=retries)
        return cls(regs, loop=loop, name=name or f"chamber[{parsed.raw}]")

    @property
    def retries(self) -> int:
        """Extra attempts for an exchange that failed on the link (the register adapter's)."""
        return self.registers.retries

    @retries.setter
    def retries(self, n: int) -> None:
        self.registers.retries = n

    # -- helpers ------------------------------------------------------------------------------------------
    def _reg(self, base: int) -> int:
        return wc.loop_register(base, self.loop)

    def _read_float(self, base: int, what: str) -> float:
        return wc.decode_float(self.registers.read(self._reg(base), 2), instrument=self.name, what=what)

    def _read_temperature(self, base: int, what: str) -> float:
        """A temperature register / °C (the display units are read once, before the first one)."""
        units = self.units
        value = self._read_float(base, what)
        return wc.f_to_c(value) if units == wc.UNITS_F else value

    @property
    def units(self) -> int:
        if self._units is None:
            units = self.registers.read(wc.DISPLAY_UNITS, 1)[0]
            if units not in (wc.UNITS_C, wc.UNITS_F):
                raise ReplyError(
                    self.name, "display units register 1328 is neither C (15) nor F (30)", reply=str(units)
                )
            self._units = units
        return self._units

    def _from_c(self, T_C: float) -> float:
        return wc.c_to_f(T_C) if self.units == wc.UNITS_F else T_C

    # -- Chamber ------------------------------------------------------------------------------------------
    def identify(self) -> str:
        part = wc.decode_string(self.registers.read(wc.PART_NUMBER, wc.PART_NUMBER_LENGTH))
        return f"Watlow F4T {part}".strip()

    def range_C(self) -> tuple[float, float]:
        """The loop's set-point range / °C (registers 2774/2776)."""
        if self._range_C is None:
            lo = self._read_temperature(wc.RANGE_LOW, "range low")
            hi = self._read_temperature(wc.RANGE_HIGH, "range high")
            self._range_C = (lo, hi)
        return self._range_C

    def set_point(self, T_degC: float) -> None:
        lo, hi = self.range_C()
        if not lo <= T_degC <= hi:
            raise InputError(f"{self.name}: set point {T_degC} degC is outside the loop range [{lo:g}, {hi:g}] degC")
        self.registers.write(self._reg(wc.SET_POINT), wc.encode_float(self._from_c(T_degC)))
        if self.registers.read(self._reg(wc.CONTROL_MODE), 1)[0] != wc.MODE_AUTO:
            self.registers.write(self._reg(wc.CONTROL_MODE), [wc.MODE_AUTO])
        back = self._read_temperature(wc.SET_POINT, "set point")
        if abs(back - T_degC) > 1e-3 * max(1.0, abs(T_degC)):
            raise InstrumentFault(self.name, f"set point read back as {back} degC, wrote {T_degC} degC")
        self._set_point_C = T_degC

    def alarms(self) -> list[str]:
        active = []
        for n in self.alarm_numbers:
            state = self.registers.read(wc.ALARM1_STATE + (n - 1) * wc.ALARM_STRIDE, 1)[0]
            if state not in wc.ALARM_INACTIVE:
                active.append(f"alarm {n} (state {state})")
        return active

    def read(self) -> float:
        active = self.alarms()
        if active:
            raise InstrumentFault(self.name, f"chamber alarm: {', '.join(active)}", causes=tuple(active))
        return self._read_temperature(wc.PROCESS_VALUE, "process value")

    def wait_stable(
        self, tol: float, timeout: float, clock: Clock, *, hold_s: float = 60.0, poll_s: float = 5.0
    ) -> float:
        sp = self._set_point_C
        if sp is None:
            sp = self._read_temperature(wc.SET_POINT, "set point")
        return wait_stable(self, sp, tol, timeout, clock, hold_s=hold_s, poll_s=poll_s)

    def close(self) -> None:
        self.registers.close()


register(CHAMBER, WatlowF4T, MODBUS_TCP, MODBUS_RTU, MODBUS_RTU_SOCKET)


def __getattr__(name: str) -> Any:  # PymodbusRegisters stays importable from here without importing pymodbus early
    if name == "PymodbusRegisters":
        from drivers.chambers.modbus import PymodbusRegisters

        return PymodbusRegisters
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["MODBUS_RTU", "MODBUS_RTU_SOCKET", "MODBUS_TCP", "WatlowF4T"]
