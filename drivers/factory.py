"""Open instruments from URLs (``battlab run --cycler URL --chamber URL``), through the drivers registered for their
schemes (:mod:`drivers.registry`).

``virtual`` starts an in-process :class:`~drivers.virtual.lab.VirtualLab` and connects to it over real
loopback sockets, so the virtual bench exercises the same drivers and wire protocols as a real one.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from drivers import registry
from drivers.interfaces import Chamber, Cycler
from drivers.registry import CHAMBER, CYCLER, OpenOptions, Role
from drivers.scpi.dialects import ScpiDialect
from drivers.urls import VIRTUAL, parse_url
from protocols.errors import InputError


def _open(role: Role, url: str, options: OpenOptions) -> Any:
    parsed = parse_url(url)
    if parsed.scheme == VIRTUAL:
        raise InputError(f"{role} URL 'virtual' needs a virtual lab: use drivers.factory.open_instruments")
    driver = registry.driver_for(role, parsed.scheme)
    if driver is None:
        forms = ", ".join(s.example for s in registry.schemes_of(role))
        raise InputError(
            f"{role} URL {url!r}: no {role} driver for scheme {parsed.scheme!r}; {role} URLs: {forms} or {VIRTUAL!r}"
        )
    return driver.open(parsed, options)


def open_cycler(
    url: str, *, dialect: ScpiDialect | None = None, timeout_s: float | None = None, retries: int = 2
) -> Cycler:
    """The cycler at ``url`` (``socket://HOST:PORT`` or a serial device path for a SCPI cycler speaking ``dialect``,
    default battlab's virtual one; ``virtual``: see open_instruments)."""
    cycler: Cycler = _open(CYCLER, url, OpenOptions(timeout_s=timeout_s, retries=retries, dialect=dialect))
    return cycler


def open_chamber(url: str, *, timeout_s: float | None = None, retries: int = 2) -> Chamber:
    """The chamber at ``url``: a Watlow F4T (``modbus-tcp://``, ``modbus-rtu://``, ``modbus-rtu+socket://``) or an
    Espec P-300 (``espec://``)."""
    chamber: Chamber = _open(CHAMBER, url, OpenOptions(timeout_s=timeout_s, retries=retries))
    return chamber


def open_instruments(
    cycler_url: str,
    chamber_url: str,
    *,
    dialect: ScpiDialect | None = None,
    lab_factory: Callable[[], object] | None = None,
) -> tuple[Cycler, Chamber, object | None]:
    """Open both instruments; if either URL is ``virtual``, start a virtual lab and use its loopback URLs.

    ``lab_factory`` builds the (unstarted) :class:`~drivers.virtual.lab.VirtualLab` (battlab passes one with
    its DFN physics); default: the stand-in physics. Returns ``(cycler, chamber, lab or None)``; the caller
    stops the lab.
    """
    lab = None
    if VIRTUAL in (cycler_url.strip(), chamber_url.strip()):
        from drivers.virtual.lab import VirtualLab

        lab = lab_factory() if lab_factory is not None else VirtualLab()
        assert isinstance(lab, VirtualLab)
        lab.start()
        if cycler_url.strip() == VIRTUAL:
            cycler_url = lab.cycler_url
            dialect = dialect or lab.config.dialect
        if chamber_url.strip() == VIRTUAL:
            chamber_url = lab.chamber_url
    try:
        cycler = open_cycler(cycler_url, dialect=dialect)
        chamber = open_chamber(chamber_url)
    except BaseException:
        if lab is not None:
            lab.stop()  # type: ignore[attr-defined]
        raise
    return cycler, chamber, lab
