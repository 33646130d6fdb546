"""The SCPI cycler driver: a :class:`~drivers.interfaces.Cycler` driven by a dialect's property table.

There are no per-command methods: :meth:`ScpiCycler.get` and :meth:`ScpiCycler.set` read the dialect's
table (command, validator, conversion), and the :class:`Cycler` methods are thin compositions of them.
Every setting is confirmed in the same round trip by an inline ``;:SYST:ERR?`` (if the dialect allows), so a
dropped command shows up as a timeout and is retried (all settings are idempotent), and an instrument error
raises :class:`InstrumentFault` at once.
"""

from __future__ import annotations

import logging
from typing import Any

from drivers.clock import Clock, RealClock, TrackedClock
from drivers.defaults import TextAdapterLink
from drivers.errors import CommunicationError, InstrumentError, InstrumentFault, NotSupported
from drivers.interfaces import CyclerCapabilities, Measurement, ProtectionState
from drivers.registry import CYCLER, OpenOptions, UrlScheme, register
from drivers.scpi import codec
from drivers.scpi.dialects import BATTLAB_VIRTUAL, ScpiDialect, ScpiProperty
from drivers.transport import LineAdapter, TextAdapter, with_retries
from drivers.urls import InstrumentURL, parse_url
from protocols.errors import InputError

log = logging.getLogger("drivers")

_MAX_ERRORS = 32

#: SCPI over a raw TCP socket, and over a serial port (the bare device path)
SOCKET = UrlScheme("socket")
SERIAL = UrlScheme("serial", options=frozenset({"baud", "timeout"}), network=False, device=True)


def dialect_capabilities(dialect: ScpiDialect, *, link_timeout: bool = False) -> CyclerCapabilities:
    """What a cycler speaking ``dialect`` can do, read from its property table."""
    clock = dialect.has("time") and dialect.has("speed")
    return CyclerCapabilities(
        clock=clock,
        timestamps=clock and "time" in dialect.measure,
        low_voltage_cutoff=dialect.has("voltage_limit_low"),
        temperature_limit=dialect.has("temperature_protection"),
        watchdog=dialect.has("watchdog_enabled") and dialect.has("watchdog_delay"),
        clear_protection=dialect.protection_clear is not None,
        link_timeout=link_timeout,
    )


class ScpiCycler(TextAdapterLink):
    """A SCPI cycler channel; ``adapter`` is its connection, ``dialect`` its command table.

    ``retries``: extra attempts for an exchange that failed on the link (timeout, garbled reply,
    disconnect); the adapter is resynchronised (``recover``) between attempts. ``capabilities`` follow from the
    dialect's table (:func:`dialect_capabilities`).
    """

    def __init__(
        self,
        adapter: TextAdapter,
        dialect: ScpiDialect = BATTLAB_VIRTUAL,
        *,
        name: str | None = None,
        retries: int = 2,
        backoff_s: float = 0.0,
    ) -> None:
        self.adapter = adapter
        self.dialect = dialect
        self.name = name or f"cycler[{adapter.name}]"
        self.retries = retries
        self.backoff_s = backoff_s
        self.capabilities = dialect_capabilities(dialect, link_timeout=adapter.timeout_s is not None)
        self.last_applied_t_s: float | None = None
        i_lo, i_hi = dialect.prop("current").values
        self._charge_max_A, self._discharge_max_A = self._battlab_current_range(i_lo, i_hi)
        if not dialect.verified:
            log.warning("%s: dialect %s is unverified against the instrument's manual", self.name, dialect.name)

    @classmethod
    def open(
        cls,
        url: str | InstrumentURL,
        dialect: ScpiDialect = BATTLAB_VIRTUAL,
        *,
        timeout_s: float | None = None,
        retries: int = 2,
        name: str | None = None,
    ) -> ScpiCycler:
        """Connect to ``socket://HOST:PORT`` or a serial device path."""
        parsed = url if isinstance(url, InstrumentURL) else parse_url(url)
        if parsed.scheme not in ("socket", "serial"):
            raise InputError(
                f"cycler URL {parsed.raw!r}: a SCPI cycler needs socket://HOST:PORT or a serial device path"
            )
        adapter = LineAdapter(
            parsed.pyserial_url,
            name=name or parsed.raw,
            timeout_s=timeout_s if timeout_s is not None else parsed.float_option("timeout", 2.0),
            baudrate=parsed.int_option("baud", 9600),
            write_terminator=dialect.write_terminator,
            read_terminator=dialect.read_terminator,
        )
        return cls(adapter, dialect, name=name or f"cycler[{parsed.raw}]", retries=retries)

    # -- the declarative core ----------------------------------------------------------------------------
    def get(self, name: str) -> Any:
        """Query property ``name`` and return it in battlab's units."""
        prop = self.dialect.prop(name)
        if not prop.queryable:
            raise InputError(f"{self.name}: property {name!r} cannot be queried")
        return self._ask(codec.query(prop.header), lambda r: self._parse(prop, r), f"query {name}")

    def set(self, name: str, value: Any, *, stamp: bool = False) -> float | None:
        """Validate ``value`` with the table's validator, convert it, send it, confirm it.

        ``stamp``: also return the instrument's time / s at which the setting took effect (dialects with a
        ``time`` property, in the same round trip), else None.
        """
        prop = self.dialect.prop(name)
        if not prop.settable:
            raise InputError(f"{self.name}: property {name!r} is read-only")
        value = prop.to_instrument(value)
        if prop.validator is not None:
            try:
                value = prop.validator(value, prop.values)
            except InputError as exc:
                unit = f" {prop.unit}" if prop.unit else ""
                raise InputError(f"{self.name}: {name} ({prop.doc}){unit}: {exc}") from None
        return self.send(codec.command(prop.header, self._format(prop, value)), what=f"set {name}", stamp=stamp)

    def send(self, command: str, *, what: str | None = None, stamp: bool = False) -> float | None:
        """Send a command and confirm it through the error queue (inline if the dialect allows).

        ``stamp``: see :meth:`set`.
        """
        what = what or command
        err_q = codec.query(self.dialect.error_query)
        t_applied: float | None = None
        if self.dialect.check_errors_inline and stamp and self.dialect.has("time"):
            time_prop = self.dialect.prop("time")

            def parse_stamped(reply: str) -> tuple[int, str, float]:
                err, t = codec.split_reply(reply, 2, instrument=self.name, what=what)
                code, message = codec.parse_error(err, instrument=self.name)
                return code, message, self._parse(time_prop, t)

            code, message, t_applied = self._ask(
                codec.compound(command, err_q, codec.query(time_prop.header)), parse_stamped, what
            )
        elif self.dialect.check_errors_inline:
            code, message = self._ask(
                codec.compound(command, err_q), lambda r: codec.parse_error(r, instrument=self.name), what
            )
        else:
            with_retries(
                self.name,
                what,
                lambda: self.adapter.write(command),
                retries=self.retries,
                recover=self.adapter.recover,
                backoff_s=self.backoff_s,
            )
            code, message = self._ask(err_q, lambda r: codec.parse_error(r, instrument=self.name), what)
        if code != 0:
            more = self.errors()
            raise InstrumentFault(
                self.name, f"{command!r} rejected: {code},{message!r}" + (f"; also {more}" if more else "")
            )
        return t_applied

    def _ask(self, command: str, parse: Any, what: str) -> Any:
        def attempt() -> Any:
            return parse(self.adapter.query(command))

        return with_retries(
            self.name,
            what,
            attempt,
            retries=self.retries,
            recover=self.adapter.recover,
            backoff_s=self.backoff_s,
        )

    def _parse(self, prop: ScpiProperty, reply: str) -> Any:
        what = f"{prop.name} ({codec.query(prop.header)})"
        if prop.kind == "float":
            raw: Any = codec.parse_number(reply, instrument=self.name, what=what)
        elif prop.kind == "int":
            raw = codec.parse_int(reply, instrument=self.name, what=what)
        elif prop.kind == "bool":
            raw = codec.parse_bool(reply, instrument=self.name, what=what)
        else:
            raw = reply.strip().strip('"')
        return prop.from_instrument(raw)

    @staticmethod
    def _format(prop: ScpiProperty, value: Any) -> str:
        if prop.kind == "bool":
            return codec.format_bool(bool(value))
        if prop.kind == "int":
            return str(int(value))
        if prop.kind == "float":
            return codec.format_number(float(value))
        return str(value)

    # -- current sign: the one place ---------------------------------------------------------------------
    def _to_instrument(self, current_A: float) -> float:
        """battlab current (positive = charge) → the instrument's sign convention."""
        return self.dialect.current_sign * current_A

    def _from_instrument(self, current: float) -> float:
        return self.dialect.current_sign * current

    def _battlab_current_range(self, lo: float, hi: float) -> tuple[float, float]:
        a, b = sorted((self._from_instrument(lo), self._from_instrument(hi)))
        return b, -a  # (largest charge, largest discharge), as magnitudes

    # -- Cycler -----------------------------------------------------------------------------------------
    def identify(self) -> str:
        reply = self._ask(
            codec.query(self.dialect.identity_query),
            lambda r: (codec.parse_idn(r, instrument=self.name), r)[1],
            "*IDN?",
        )
        return reply.strip()

    def initialize(self) -> None:
        self.send(self.dialect.clear_status, what="clear status")
        self.set("output", False)
        if self.dialect.has("function") and self.dialect.priority_current:
            self.set("function", self.dialect.priority_current)
        self.set("current", 0.0)

    def set_current(self, current_A: float) -> None:
        if not (-self._discharge_max_A <= current_A <= self._charge_max_A):
            raise InputError(
                f"{self.name}: current {current_A:g} A is outside the configured limits "
                f"[-{self._discharge_max_A:g}, {self._charge_max_A:g}] A (positive = charge)"
            )
        self.last_applied_t_s = self.set("current", self._to_instrument(current_A), stamp=True)

    def output(self, on: bool) -> None:
        self.set("output", bool(on))

    def measure(self) -> Measurement:
        props = [self.dialect.prop(n) for n in self.dialect.measure]
        if self.dialect.compound and len(props) > 1:
            cmd = codec.compound(*(codec.query(p.header) for p in props))

            def parse(reply: str) -> list[Any]:
                parts = codec.split_reply(reply, len(props), instrument=self.name, what="measure")
                return [self._parse(p, part) for p, part in zip(props, parts, strict=True)]

            values = self._ask(cmd, parse, "measure")
        else:
            values = [self.get(p.name) for p in props]
        got = dict(zip(self.dialect.measure, values, strict=True))
        if "voltage" not in got or "current_measured" not in got:
            raise InputError(f"dialect {self.dialect.name}: measure must include voltage and current_measured")
        return Measurement(
            voltage_V=got["voltage"],
            current_A=self._from_instrument(got["current_measured"]),
            temperature_K=got.get("temperature"),
            t_s=got.get("time"),
        )

    def set_voltage_limits(self, low_V: float | None, high_V: float) -> None:
        if low_V is not None and not low_V < high_V:
            raise InputError(f"{self.name}: voltage limits need low < high, got {low_V} and {high_V} V")
        if low_V is not None and not self.capabilities.low_voltage_cutoff:
            raise NotSupported(
                self.name,
                "a low-voltage cut-off",
                f"dialect {self.dialect.name} has no low-voltage cutoff; pass low_V=None and let the runner enforce it",
            )
        self.set("voltage_limit", high_V)
        if low_V is not None:
            self.set("voltage_limit_low", low_V)

    def set_current_limits(self, charge_A: float, discharge_A: float) -> None:
        if not (charge_A >= 0 and discharge_A >= 0):
            raise InputError(f"{self.name}: current limits are magnitudes >= 0, got {charge_A}, {discharge_A}")
        i_lo, i_hi = self.dialect.prop("current").values
        charge_max, discharge_max = self._battlab_current_range(i_lo, i_hi)
        if charge_A > charge_max or discharge_A > discharge_max:
            raise InputError(
                f"{self.name}: current limits {charge_A:g} A charge / {discharge_A:g} A "
                f"discharge exceed the instrument's {charge_max:g} / {discharge_max:g} A"
            )
        pos, neg = (charge_A, discharge_A) if self.dialect.current_sign > 0 else (discharge_A, charge_A)
        if self.dialect.has("current_limit"):
            self.set("current_limit", pos)
        if self.dialect.has("current_limit_neg"):
            self.set("current_limit_neg", -neg)
        self._charge_max_A, self._discharge_max_A = charge_A, discharge_A

    def set_temperature_limit(self, T_max_K: float) -> None:
        """Instrument-side over-temperature trip (only dialects with a temperature probe)."""
        if not self.capabilities.temperature_limit:
            raise NotSupported(
                self.name, "an over-temperature trip", f"dialect {self.dialect.name} has no temperature_protection"
            )
        self.set("temperature_protection", T_max_K)

    def protection(self) -> ProtectionState:
        raw = int(self.get("questionable"))
        return ProtectionState(tripped=self.dialect.tripped(raw), causes=self.dialect.status_names(raw), raw=raw)

    def clear_protection(self) -> None:
        if self.dialect.protection_clear is None:
            raise NotSupported(
                self.name, "clearing protection remotely", f"dialect {self.dialect.name} has no protection clear"
            )
        # Safety first: the output is programmed off before the latch is cleared, so clearing never
        # re-enables it (Keysight restores the programmed state on clear).
        self.set("output", False)
        self.send(codec.command(self.dialect.protection_clear), what="clear protection")

    def errors(self) -> list[tuple[int, str]]:
        out: list[tuple[int, str]] = []
        err_q = codec.query(self.dialect.error_query)
        for _ in range(_MAX_ERRORS):
            code, message = self._ask(err_q, lambda r: codec.parse_error(r, instrument=self.name), "SYST:ERR?")
            if code == 0:
                return out
            out.append((code, message))
        raise InstrumentFault(self.name, f"error queue did not empty after {_MAX_ERRORS} reads: {out}")

    def set_watchdog(self, timeout_s: float | None) -> None:
        if not self.capabilities.watchdog:
            raise NotSupported(self.name, "an instrument watchdog", f"dialect {self.dialect.name} has none")
        if timeout_s is None:
            self.set("watchdog_enabled", False)
            return
        self.set("watchdog_delay", timeout_s)
        self.set("watchdog_enabled", True)

    def safe_off(self) -> bool:
        try:
            self.set("output", False)
            return True
        except (InstrumentError, OSError) as exc:
            log.error("%s: safe_off could not confirm output off: %s", self.name, exc)
        try:  # last resort, unconfirmed
            self.adapter.write(codec.command(self.dialect.prop("output").header, "0"))
        except (InstrumentError, OSError) as exc:
            log.error("%s: safe_off last-resort write failed: %s", self.name, exc)
        return False

    def send_off(self) -> bool:
        """Output off without waiting for a confirmation, for a link known to be dead: one write, never raises;
        True if it was sent."""
        try:
            self.adapter.write(codec.command(self.dialect.prop("output").header, "0"))
            return True
        except (InstrumentError, OSError) as exc:
            log.error("%s: output off could not be sent: %s", self.name, exc)
            return False

    def close(self) -> None:
        self.adapter.close()

    # -- time -------------------------------------------------------------------------------------------
    _clock: TrackedClock | None = None

    def clock(self) -> Clock:
        """The instrument's clock if it has one (virtual tester), else wall time."""
        if self.capabilities.clock:
            if self._clock is None:
                self._clock = TrackedClock(lambda: float(self.get("time")), float(self.get("speed")))
            return self._clock
        return RealClock()


def _open(url: InstrumentURL, options: OpenOptions) -> ScpiCycler:
    dialect = options.dialect or BATTLAB_VIRTUAL
    return ScpiCycler.open(url, dialect, timeout_s=options.timeout_s, retries=options.retries)


register(CYCLER, ScpiCycler, SOCKET, SERIAL, opener=_open)

__all__ = ["SERIAL", "SOCKET", "ScpiCycler", "CommunicationError", "dialect_capabilities"]
