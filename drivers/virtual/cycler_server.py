"""The virtual cycler's SCPI server: the dialect's property table, served over a loopback socket.

Each received message advances the lab to "now", resets the instrument watchdog, then executes its program
units in order. Errors go to the error queue (``SYST:ERR?``) exactly as on a real instrument: an unknown
header gives ``-113,"Undefined header"``, a bad value ``-222,"Data out of range"``; a query that fails
produces no reply.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Any

from drivers.scpi import codec
from drivers.scpi.dialects import ScpiDialect, ScpiProperty
from drivers.virtual.faults import FaultInjector
from drivers.virtual.instruments import ExecutionError, SimulatedCycler
from drivers.virtual.served import ServedLab
from drivers.virtual.textserver import LineServer


class ScpiCyclerServer:
    """Serve ``dialect`` for ``lab.cycler`` on ``host:port``."""

    def __init__(
        self,
        lab: ServedLab,
        dialect: ScpiDialect,
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        faults: FaultInjector | None = None,
    ) -> None:
        self.lab = lab
        self.dialect = dialect
        self.server = LineServer(
            "virtual-cycler",
            self.handle,
            host=host,
            port=port,
            read_terminator=dialect.write_terminator,
            write_terminator=dialect.read_terminator,
            faults=faults,
        )
        self._props: list[tuple[re.Pattern[str], ScpiProperty]] = [
            (codec.header_regex(p.header), p) for p in dialect.properties
        ]
        self._commands: list[tuple[re.Pattern[str], Callable[[SimulatedCycler, bool], str | None]]] = [
            (codec.header_regex(dialect.identity_query), self._idn),
            (codec.header_regex(dialect.error_query), self._error),
            (codec.header_regex(dialect.clear_status), self._cls),
            (codec.header_regex("*OPC"), lambda c, q: "1" if q else None),
        ]
        if dialect.protection_clear:
            self._commands.append((codec.header_regex(dialect.protection_clear), self._prot_clear))

    @property
    def url(self) -> str:
        return self.server.url

    def start(self) -> None:
        self.server.start()

    def stop(self) -> None:
        self.server.stop()

    # -- dispatch ---------------------------------------------------------------------------------------
    def handle(self, line: str) -> str | None:
        with self.lab.lock:
            t = self.lab.exchange()
            cycler = self.lab.cycler
            cycler.note_io(t)
            replies: list[str] = []
            for unit in codec.parse_program_message(line):
                try:
                    reply = self._execute(cycler, unit)
                except ExecutionError as exc:
                    cycler.push_error(exc.code, exc.message)
                    continue
                if unit.is_query and reply is not None:
                    replies.append(reply)
            return ";".join(replies) if replies else None

    def _execute(self, cycler: SimulatedCycler, unit: codec.ProgramUnit) -> str | None:
        for regex, handler in self._commands:
            if regex.match(unit.header):
                if unit.args:
                    raise ExecutionError(-108, "Parameter not allowed")
                return handler(cycler, unit.is_query)
        for regex, prop in self._props:
            if regex.match(unit.header):
                if unit.is_query:
                    if not prop.queryable:
                        raise ExecutionError(-113, "Undefined header")
                    return self._format(prop, self._get(cycler, prop.name))
                if not prop.settable:
                    raise ExecutionError(-113, "Undefined header")
                if len(unit.args) != 1:
                    raise ExecutionError(
                        -109 if not unit.args else -108,
                        "Missing parameter" if not unit.args else "Parameter not allowed",
                    )
                self._set(cycler, prop, self._parse(prop, unit.args[0]))
                return None
        raise ExecutionError(-113, "Undefined header")

    # -- common commands --------------------------------------------------------------------------------
    def _idn(self, cycler: SimulatedCycler, query: bool) -> str:
        if not query:
            raise ExecutionError(-113, "Undefined header")
        return self.dialect.sim_identity

    def _error(self, cycler: SimulatedCycler, query: bool) -> str:
        if not query:
            raise ExecutionError(-113, "Undefined header")
        return codec.format_error(*cycler.pop_error())

    def _cls(self, cycler: SimulatedCycler, query: bool) -> None:
        if query:
            raise ExecutionError(-113, "Undefined header")
        cycler.errors.clear()
        return None

    def _prot_clear(self, cycler: SimulatedCycler, query: bool) -> None:
        if query:
            raise ExecutionError(-113, "Undefined header")
        cycler.clear_protection()
        return None

    # -- properties (instrument units) ------------------------------------------------------------------
    @staticmethod
    def _parse(prop: ScpiProperty, arg: str) -> Any:
        try:
            if prop.kind == "bool":
                return codec.parse_bool_arg(arg)
            if prop.kind == "str":
                return arg.strip().strip('"').upper()
            value = codec.parse_value(arg)
        except ValueError:
            raise ExecutionError(-104, "Data type error") from None
        if prop.kind == "int":
            if value != int(value):
                raise ExecutionError(-224, "Illegal parameter value")
            value = int(value)
        if (
            prop.values is not None
            and isinstance(prop.values, tuple)
            and len(prop.values) == 2
            and not prop.values[0] <= value <= prop.values[1]
        ):
            raise ExecutionError(-222, "Data out of range")
        return value

    @staticmethod
    def _format(prop: ScpiProperty, value: Any) -> str:
        if prop.kind == "bool":
            return "1" if value else "0"
        if prop.kind == "int":
            return str(int(value))
        if prop.kind == "float":
            return codec.format_nr3(float(value), prop.digits)
        return str(value)

    def _get(self, c: SimulatedCycler, name: str) -> Any:
        getters: dict[str, Callable[[], Any]] = {
            "function": lambda: c.function,
            "current": lambda: c.current,
            "voltage_limit": lambda: c.voltage_limit,
            "voltage_limit_low": lambda: c.voltage_limit_low if c.voltage_limit_low is not None else 0.0,
            "current_limit": lambda: c.current_limit,
            "current_limit_neg": lambda: c.current_limit_neg,
            "ovp": lambda: c.ovp,
            "output": lambda: c.output_on,
            "watchdog_enabled": lambda: c.watchdog_enabled,
            "watchdog_delay": lambda: c.watchdog_delay_s,
            "questionable": lambda: c.status,
            "voltage": c.measure_voltage,
            "current_measured": c.measure_current,
            "temperature": lambda: c.measure_temperature_K() - 273.15,
            "temperature_protection": lambda: c.temperature_protection_K - 273.15,
            "time": lambda: c.t,
            "speed": lambda: self.lab.clock.speed,
        }
        if name not in getters:
            raise ExecutionError(-113, "Undefined header")
        return getters[name]()

    def _set(self, c: SimulatedCycler, prop: ScpiProperty, value: Any) -> None:
        name = prop.name
        if name == "function":
            c.set_function(value)
        elif name == "current":
            c.set_current(value)
        elif name == "output":
            c.set_output(value)
        elif name == "watchdog_enabled":
            c.watchdog_enabled = value
            c.note_io(c.t)
        elif name == "watchdog_delay":
            c.watchdog_delay_s = value
        elif name == "temperature_protection":
            c.temperature_protection_K = value + 273.15
        elif name in ("voltage_limit", "voltage_limit_low", "current_limit", "current_limit_neg", "ovp"):
            setattr(c, name, value)
        else:
            raise ExecutionError(-113, "Undefined header")
