"""Open instruments from URLs (``battlab run --cycler URL --chamber URL``).

``virtual`` starts an in-process :class:`~drivers.virtual.lab.VirtualLab` and connects to it over real
loopback sockets, so the virtual bench exercises the same drivers and wire protocols as a real one.
"""

from __future__ import annotations

from collections.abc import Callable

from drivers.chambers.espec import EspecP300
from drivers.chambers.watlow_f4t import WatlowF4T
from drivers.interfaces import Chamber, Cycler
from drivers.scpi.cycler import ScpiCycler
from drivers.scpi.dialects import BATTLAB_VIRTUAL, ScpiDialect
from drivers.urls import parse_url
from protocols.errors import InputError


def open_cycler(
    url: str, *, dialect: ScpiDialect | None = None, timeout_s: float | None = None, retries: int = 2
) -> Cycler:
    """A SCPI cycler at ``socket://HOST:PORT`` or a serial device path (``virtual``: see open_instruments)."""
    parsed = parse_url(url)
    if parsed.scheme == "virtual":
        raise InputError("cycler URL 'virtual' needs a virtual lab: use drivers.factory.open_instruments")
    return ScpiCycler.open(parsed, dialect or BATTLAB_VIRTUAL, timeout_s=timeout_s, retries=retries)


def open_chamber(url: str, *, timeout_s: float | None = None, retries: int = 2) -> Chamber:
    """A Watlow F4T (``modbus-tcp://``, ``modbus-rtu://``, ``modbus-rtu+socket://``) or an Espec P-300
    (``espec://``)."""
    parsed = parse_url(url)
    if parsed.scheme in ("modbus-tcp", "modbus-rtu", "modbus-rtu+socket"):
        return WatlowF4T.open(parsed, timeout_s=timeout_s, retries=retries)
    if parsed.scheme == "espec":
        return EspecP300.open(parsed, timeout_s=timeout_s, retries=retries)
    raise InputError(
        f"chamber URL {url!r}: expected modbus-tcp://, modbus-rtu://, modbus-rtu+socket://, espec:// or 'virtual'"
    )


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
    if "virtual" in (cycler_url.strip(), chamber_url.strip()):
        from drivers.virtual.lab import VirtualLab

        lab = lab_factory() if lab_factory is not None else VirtualLab()
        assert isinstance(lab, VirtualLab)
        lab.start()
        if cycler_url.strip() == "virtual":
            cycler_url = lab.cycler_url
            dialect = dialect or lab.config.dialect
        if chamber_url.strip() == "virtual":
            chamber_url = lab.chamber_url
    try:
        cycler = open_cycler(cycler_url, dialect=dialect)
        chamber = open_chamber(chamber_url)
    except BaseException:
        if lab is not None:
            lab.stop()  # type: ignore[attr-defined]
        raise
    return cycler, chamber, lab
