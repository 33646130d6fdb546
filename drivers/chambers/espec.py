"""Espec P-300 controller over its text protocol (TCP or serial): a :class:`Chamber`."""

from __future__ import annotations

from collections.abc import Callable
from typing import TypeVar

from drivers.chambers import espec_codec as ec
from drivers.chambers.base import wait_stable
from drivers.clock import Clock
from drivers.defaults import TextAdapterLink
from drivers.errors import InstrumentFault
from drivers.interfaces import ChamberCapabilities
from drivers.registry import CHAMBER, UrlScheme, register
from drivers.transport import LineAdapter, TextAdapter, with_retries
from drivers.urls import InstrumentURL, parse_url
from protocols.errors import InputError

T = TypeVar("T")

#: the P-300's text protocol over TCP (port 10001 by default) or a serial port
ESPEC = UrlScheme("espec", options=frozenset({"baud", "timeout"}), default_port=10001, device=True)


class EspecP300(TextAdapterLink):
    """P-300 temperature loop; ``adapter`` speaks CR LF lines."""

    def __init__(self, adapter: TextAdapter, *, name: str | None = None, retries: int = 2) -> None:
        self.adapter = adapter
        self.name = name or f"chamber[{adapter.name}]"
        self.retries = retries
        self.capabilities = ChamberCapabilities(link_timeout=adapter.timeout_s is not None)
        self._set_point_C: float | None = None

    @classmethod
    def open(
        cls,
        url: str | InstrumentURL,
        *,
        timeout_s: float | None = None,
        retries: int = 2,
        name: str | None = None,
    ) -> EspecP300:
        parsed = url if isinstance(url, InstrumentURL) else parse_url(url)
        if parsed.scheme != "espec":
            raise InputError(
                f"chamber URL {parsed.raw!r}: an Espec P-300 needs espec://HOST:PORT or espec:///dev/DEVICE"
            )
        adapter = LineAdapter(
            parsed.pyserial_url,
            name=name or parsed.raw,
            timeout_s=timeout_s if timeout_s is not None else parsed.float_option("timeout", 2.0),
            baudrate=parsed.int_option("baud", 9600),
            write_terminator="\r\n",
            read_terminator="\r\n",
        )
        return cls(adapter, name=name or f"chamber[{parsed.raw}]", retries=retries)

    def _ask(self, command: str, parse: Callable[[str], T], what: str | None = None) -> T:
        return with_retries(
            self.name,
            what or command,
            lambda: parse(self.adapter.query(command)),
            retries=self.retries,
            recover=self.adapter.recover,
        )

    def _set(self, command: str) -> None:
        self._ask(command, lambda r: ec.parse_ok(r, instrument=self.name, command=command))

    # -- Chamber ------------------------------------------------------------------------------------------
    def identify(self) -> str:
        return "Espec " + self._ask(
            "TYPE?", lambda r: (ec.check_na(r, instrument=self.name, command="TYPE?"), r.strip())[1]
        )

    def status(self) -> ec.TempStatus:
        return self._ask("TEMP?", lambda r: ec.parse_temp(r, instrument=self.name))

    def set_point(self, T_degC: float) -> None:
        st = self.status()
        if not st.lower_C <= T_degC <= st.upper_C:
            raise InputError(
                f"{self.name}: set point {T_degC} degC is outside the chamber's limits "
                f"[{st.lower_C:g}, {st.upper_C:g}] degC"
            )
        self._set(ec.set_point_command(T_degC))
        self._set(ec.mode_command("CONSTANT"))
        back = self.status().sp_C
        if abs(back - round(T_degC, 1)) > 0.051:
            raise InstrumentFault(self.name, f"set point read back as {back} degC, wrote {T_degC:.1f} degC")
        self._set_point_C = T_degC

    def alarms(self) -> list[str]:
        codes = self._ask("ALARM?", lambda r: ec.parse_alarm(r, instrument=self.name))
        return [f"alarm code {c}" for c in codes]

    def read(self) -> float:
        mon = self._ask("MON?", lambda r: ec.parse_mon(r, instrument=self.name))
        if mon.alarms:
            active = self.alarms() or [f"{mon.alarms} alarm(s)"]
            raise InstrumentFault(self.name, f"chamber alarm: {', '.join(active)}", causes=tuple(active))
        return mon.T_C

    def wait_stable(
        self, tol: float, timeout: float, clock: Clock, *, hold_s: float = 60.0, poll_s: float = 5.0
    ) -> float:
        sp = self._set_point_C if self._set_point_C is not None else self.status().sp_C
        return wait_stable(self, sp, tol, timeout, clock, hold_s=hold_s, poll_s=poll_s)

    def close(self) -> None:
        self.adapter.close()


register(CHAMBER, EspecP300, ESPEC)
