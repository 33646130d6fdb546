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

Each scheme's syntax (host and port, device path, default port, options) is declared by the driver that registers
it (:mod:`drivers.registry`); this table lists the in-tree ones. A URL that does not fit raises
:class:`protocols.errors.InputError` naming it and the registered forms.
"""

from __future__ import annotations

import re
from urllib.parse import parse_qsl, urlsplit

from drivers import registry
from drivers.instrument_url import InstrumentURL
from protocols.errors import InputError

VIRTUAL = "virtual"
_DEVICE_RE = re.compile(r"^(/dev/[\w./-]+|COM\d+|loop://.*)$")


def expected_forms() -> str:
    """The registered URL forms, for messages: ``socket://HOST:PORT, a serial device path, ... or 'virtual'``."""
    return ", ".join(scheme.example for scheme in registry.url_schemes()) + f" or {VIRTUAL!r}"


def _bad(url: str, why: str) -> InputError:
    return InputError(f"instrument URL {url!r}: {why}; expected {expected_forms()}")


def parse_url(url: str) -> InstrumentURL:
    """Parse an instrument URL (see the module docstring); raise InputError naming a bad one."""
    if not isinstance(url, str) or not url.strip():
        raise _bad(str(url), "empty")
    url = url.strip()
    if url == VIRTUAL:
        return InstrumentURL(raw=url, scheme=VIRTUAL)
    path_part, _, query = url.partition("?")
    if _DEVICE_RE.match(path_part):
        serial = registry.url_scheme("serial")
        if serial is None:
            raise _bad(url, "no registered driver opens a bare serial device path")
        return InstrumentURL(raw=url, scheme="serial", device=path_part, options=_options(url, serial, query))
    if "://" not in url:
        raise _bad(url, "no scheme and not a device path")
    parts = urlsplit(url)
    name = parts.scheme.lower()
    spec = registry.url_scheme(name) if name != "serial" else None
    if spec is None:
        raise _bad(url, f"unknown scheme {parts.scheme!r}")
    options = _options(url, spec, parts.query)
    if spec.device and not parts.netloc and parts.path:
        if not _DEVICE_RE.match(parts.path):
            raise _bad(url, f"{parts.path!r} is not a serial device path")
        return InstrumentURL(raw=url, scheme=name, device=parts.path, options=options)
    if not spec.network:
        raise _bad(url, f"{name} needs a device path ({name}:///dev/ttyUSB1)")
    if parts.path not in ("", "/"):
        raise _bad(url, f"unexpected path {parts.path!r}")
    try:
        host, port = parts.hostname, parts.port
    except ValueError as exc:
        raise _bad(url, f"bad port ({exc})") from None
    if not host:
        raise _bad(url, "no host")
    port = port if port is not None else spec.default_port
    if port is None:
        raise _bad(url, "no port")
    if not 0 < port < 65536:
        raise _bad(url, f"port {port} out of range")
    return InstrumentURL(raw=url, scheme=name, host=host, port=port, options=options)


def _options(url: str, spec: registry.UrlScheme, query: str) -> dict[str, str]:
    try:
        pairs = parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query))
    except ValueError:
        raise _bad(url, f"bad options {query!r}") from None
    options = dict(pairs)
    unknown = set(options) - spec.options
    if unknown:
        raise _bad(
            url,
            f"unknown option(s) {sorted(unknown)} for {spec.name} (allowed: {sorted(spec.options)})",
        )
    return options
