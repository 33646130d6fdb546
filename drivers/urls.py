"""Instrument URLs.

=======================================  ==========================================================
``socket://127.0.0.1:5025``              SCPI over a raw TCP socket (pyserial URL syntax)
``/dev/ttyUSB0``, ``COM3``               SCPI over a serial port; options ``?baud=115200``
``modbus-tcp://HOST:502``                Watlow F4T, Modbus TCP; options ``?unit=1``
``modbus-rtu:///dev/ttyUSB1?baud=38400`` Watlow F4T, Modbus RTU on a serial port; ``unit``, ``parity``
``modbus-rtu+socket://127.0.0.1:PORT``   Modbus RTU framing over a TCP socket (a serial-to-Ethernet
                                         gateway, or the virtual tester's RTU server in tests)
``espec://HOST:10001``                   Espec P-300 text protocol over TCP (default port 10001)
``espec:///dev/ttyS0?baud=9600``         Espec P-300 text protocol over a serial port
``virtual``                              the in-process virtual tester
=======================================  ==========================================================

A URL that does not fit raises :class:`protocols.errors.InputError` naming it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from urllib.parse import parse_qsl, urlsplit

from protocols.errors import InputError

SCHEMES = ("socket", "serial", "modbus-tcp", "modbus-rtu", "modbus-rtu+socket", "espec", "virtual")
_DEFAULT_PORTS = {"modbus-tcp": 502, "espec": 10001}
_ALLOWED_OPTIONS = {
    "socket": {"timeout"},
    "serial": {"baud", "timeout"},
    "modbus-tcp": {"unit", "timeout"},
    "modbus-rtu": {"unit", "baud", "parity", "stopbits", "timeout"},
    "modbus-rtu+socket": {"unit", "timeout"},
    "espec": {"baud", "timeout"},
    "virtual": set(),
}
_DEVICE_RE = re.compile(r"^(/dev/[\w./-]+|COM\d+|loop://.*)$")


@dataclass(frozen=True)
class InstrumentURL:
    """A parsed instrument URL.

    ``scheme`` is one of :data:`SCHEMES`; ``host``/``port`` for TCP links; ``device`` for serial ports;
    ``options`` the query string (``baud``, ``unit``, ``parity``, ``stopbits``, ``timeout``).
    """

    raw: str
    scheme: str
    host: str | None = None
    port: int | None = None
    device: str | None = None
    options: dict[str, str] = field(default_factory=dict)

    @property
    def pyserial_url(self) -> str:
        """The pyserial ``serial_for_url`` argument for this link (``socket://h:p`` or a device path)."""
        if self.device is not None:
            return self.device
        return f"socket://{self.host}:{self.port}"

    def option(self, key: str, default: str | None = None) -> str | None:
        return self.options.get(key, default)

    def int_option(self, key: str, default: int) -> int:
        value = self.options.get(key)
        if value is None:
            return default
        try:
            return int(value)
        except ValueError:
            raise InputError(f"instrument URL {self.raw!r}: option {key}={value!r} is not an integer") from None

    def float_option(self, key: str, default: float) -> float:
        value = self.options.get(key)
        if value is None:
            return default
        try:
            return float(value)
        except ValueError:
            raise InputError(f"instrument URL {self.raw!r}: option {key}={value!r} is not a number") from None


def _bad(url: str, why: str) -> InputError:
    return InputError(
        f"instrument URL {url!r}: {why}; expected socket://HOST:PORT, a serial device path, "
        "modbus-tcp://HOST[:PORT], modbus-rtu:///dev/DEVICE?baud=N, modbus-rtu+socket://HOST:PORT, "
        "espec://HOST[:PORT] or 'virtual'"
    )


def parse_url(url: str) -> InstrumentURL:
    """Parse an instrument URL (see the module docstring); raise InputError naming a bad one."""
    if not isinstance(url, str) or not url.strip():
        raise _bad(str(url), "empty")
    url = url.strip()
    if url == "virtual":
        return InstrumentURL(raw=url, scheme="virtual")
    path_part, _, query = url.partition("?")
    if _DEVICE_RE.match(path_part):
        return InstrumentURL(raw=url, scheme="serial", device=path_part, options=_options(url, "serial", query))
    if "://" not in url:
        raise _bad(url, "no scheme and not a device path")
    parts = urlsplit(url)
    scheme = parts.scheme.lower()
    if scheme not in SCHEMES or scheme == "serial":
        raise _bad(url, f"unknown scheme {parts.scheme!r}")
    options = _options(url, scheme, parts.query)
    if scheme in ("modbus-rtu", "espec") and not parts.netloc and parts.path:
        if not _DEVICE_RE.match(parts.path):
            raise _bad(url, f"{parts.path!r} is not a serial device path")
        return InstrumentURL(raw=url, scheme=scheme, device=parts.path, options=options)
    if scheme == "modbus-rtu":
        raise _bad(url, "modbus-rtu needs a device path (modbus-rtu:///dev/ttyUSB1)")
    if parts.path not in ("", "/"):
        raise _bad(url, f"unexpected path {parts.path!r}")
    try:
        host, port = parts.hostname, parts.port
    except ValueError as exc:
        raise _bad(url, f"bad port ({exc})") from None
    if not host:
        raise _bad(url, "no host")
    port = port if port is not None else _DEFAULT_PORTS.get(scheme)
    if port is None:
        raise _bad(url, "no port")
    if not 0 < port < 65536:
        raise _bad(url, f"port {port} out of range")
    return InstrumentURL(raw=url, scheme=scheme, host=host, port=port, options=options)


def _options(url: str, scheme: str, query: str) -> dict[str, str]:
    try:
        pairs = parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query))
    except ValueError:
        raise _bad(url, f"bad options {query!r}") from None
    options = dict(pairs)
    unknown = set(options) - _ALLOWED_OPTIONS[scheme]
    if unknown:
        raise _bad(
            url,
            f"unknown option(s) {sorted(unknown)} for {scheme} (allowed: {sorted(_ALLOWED_OPTIONS[scheme])})",
        )
    return options
