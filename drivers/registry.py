"""Instrument drivers found by URL scheme.

Each driver module registers its class once, with the URL schemes it opens and how they are written::

    register(CYCLER, ScpiCycler, SOCKET, SERIAL, opener=_open)      # drivers/scpi/cycler.py
    register(CHAMBER, EspecP300, UrlScheme("espec", ..., default_port=10001, device=True))

:func:`drivers.urls.parse_url` reads the schemes' syntax from here, and :func:`drivers.factory.open_cycler` /
``open_chamber`` the driver. The in-tree driver modules (:data:`DRIVER_MODULES`) are imported on the first lookup,
so importing ``drivers`` stays light (no pymodbus); a driver elsewhere registers by being imported.
"""

from __future__ import annotations

import importlib
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

from drivers.instrument_url import InstrumentURL

if TYPE_CHECKING:
    from drivers.scpi.dialects import ScpiDialect

Role = Literal["cycler", "chamber"]
CYCLER: Role = "cycler"
CHAMBER: Role = "chamber"

#: the modules that register the in-tree drivers: a new driver module adds its line here
DRIVER_MODULES: tuple[str, ...] = (
    "drivers.scpi.cycler",
    "drivers.chambers.watlow_f4t",
    "drivers.chambers.espec",
)


@dataclass(frozen=True)
class UrlScheme:
    """How URLs of scheme ``name`` are written.

    ``network``: ``name://HOST:PORT`` (the port may be left out when there is a ``default_port``); ``device``:
    ``name:///dev/DEVICE`` (a serial device path); ``options``: the query options allowed (``?baud=9600``).
    The scheme ``serial`` is written as the bare device path (``/dev/ttyUSB0``, ``COM3``).
    """

    name: str
    options: frozenset[str] = frozenset({"timeout"})
    default_port: int | None = None
    network: bool = True
    device: bool = False

    @property
    def example(self) -> str:
        """The URL forms, for messages (e.g. ``espec://HOST[:PORT] or espec:///dev/DEVICE``)."""
        if self.name == "serial":
            return "a serial device path"
        forms = []
        if self.network:
            forms.append(f"{self.name}://HOST" + ("[:PORT]" if self.default_port is not None else ":PORT"))
        if self.device:
            forms.append(f"{self.name}:///dev/DEVICE")
        return " or ".join(forms)


@dataclass(frozen=True)
class OpenOptions:
    """How to open an instrument: ``timeout_s`` the link's read timeout / s (None: the URL's ``timeout=`` option,
    else the driver's default), ``retries`` the driver's own extra attempts for a failed exchange, ``dialect`` the
    SCPI dialect of a SCPI cycler (drivers that are not SCPI ignore it)."""

    timeout_s: float | None = None
    retries: int = 2
    dialect: ScpiDialect | None = None


#: opens a driver's instrument from a parsed URL
Opener = Callable[["InstrumentURL", OpenOptions], Any]


@dataclass(frozen=True)
class Driver:
    """A registered driver: its role, its class (checked against the role's interface by the tests), its schemes
    and how it is opened."""

    role: Role
    cls: type
    schemes: tuple[UrlScheme, ...]
    opener: Opener = field(compare=False)

    def open(self, url: InstrumentURL, options: OpenOptions) -> Any:
        return self.opener(url, options)


_drivers: dict[tuple[Role, str], Driver] = {}
_schemes: dict[str, UrlScheme] = {}
_lock = threading.RLock()
_loaded = False


def _default_opener(cls: type) -> Opener:
    """``cls.open(url, timeout_s=..., retries=...)``: the convention of drivers without a dialect."""

    def opener(url: InstrumentURL, options: OpenOptions) -> Any:
        return cls.open(url, timeout_s=options.timeout_s, retries=options.retries)  # type: ignore[attr-defined]

    return opener


def register(role: Role, cls: type, *schemes: UrlScheme, opener: Opener | None = None) -> Driver:
    """Register driver ``cls`` for ``role`` under ``schemes`` (one line in the driver's module).

    ``opener(url, options)`` opens it (default: ``cls.open(url, timeout_s=..., retries=...)``). A scheme is taken by
    one driver per role, and its syntax is the same whichever role uses it; breaking either is a ValueError.
    """
    if role not in (CYCLER, CHAMBER):
        raise ValueError(f"driver {cls.__name__}: role {role!r} is neither {CYCLER!r} nor {CHAMBER!r}")
    if not schemes:
        raise ValueError(f"driver {cls.__name__}: no URL scheme")
    driver = Driver(role, cls, schemes, opener or _default_opener(cls))
    with _lock:
        for scheme in schemes:
            taken = _drivers.get((role, scheme.name))
            if taken is not None and taken.cls is not cls:
                raise ValueError(f"{role} URL scheme {scheme.name!r} is taken by {taken.cls.__name__}")
            known = _schemes.get(scheme.name)
            if known is not None and known != scheme:
                raise ValueError(f"URL scheme {scheme.name!r} is registered with another syntax: {known}")
        for scheme in schemes:
            _drivers[(role, scheme.name)] = driver
            _schemes[scheme.name] = scheme
    return driver


def unregister(driver: Driver) -> None:
    """Remove ``driver`` (and the schemes no other driver uses)."""
    with _lock:
        for key in [k for k, d in _drivers.items() if d is driver]:
            del _drivers[key]
        used = {name for _, name in _drivers}
        for name in [n for n in _schemes if n not in used]:
            del _schemes[name]


def _load() -> None:
    global _loaded
    if _loaded:
        return
    with _lock:
        if not _loaded:
            for module in DRIVER_MODULES:
                importlib.import_module(module)
            _loaded = True


def url_scheme(name: str) -> UrlScheme | None:
    """The syntax of a registered URL scheme, or None."""
    _load()
    return _schemes.get(name)


def url_schemes() -> tuple[UrlScheme, ...]:
    """Every registered URL scheme, in registration order."""
    _load()
    return tuple(_schemes.values())


def drivers(role: Role | None = None) -> tuple[Driver, ...]:
    """The registered drivers (of ``role``), each once, in registration order."""
    _load()
    out: list[Driver] = []
    for (r, _), d in _drivers.items():
        if (role is None or r == role) and d not in out:
            out.append(d)
    return tuple(out)


def driver_for(role: Role, scheme: str) -> Driver | None:
    """The ``role`` driver registered for ``scheme``, or None."""
    _load()
    return _drivers.get((role, scheme))


def schemes_of(role: Role) -> tuple[UrlScheme, ...]:
    """The URL schemes that open a ``role`` (for messages)."""
    _load()
    return tuple(_schemes[name] for r, name in _drivers if r == role)


__all__ = [
    "CHAMBER",
    "CYCLER",
    "DRIVER_MODULES",
    "Driver",
    "OpenOptions",
    "Opener",
    "Role",
    "UrlScheme",
    "driver_for",
    "drivers",
    "register",
    "schemes_of",
    "unregister",
    "url_scheme",
    "url_schemes",
]
