"""The bench: where and on what a plan runs (:class:`RunSettings`), the instruments opened from their URLs (and the
in-process virtual tester for ``virtual`` URLs), their limits and link settings, and the check that each answers
before a run is catalogued (:func:`connect_bench`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

from battlab.lab.limits import VIRTUAL_LIMITS, InstrumentLimits
from drivers.clock import Clock, RealClock
from drivers.errors import InstrumentError
from drivers.interfaces import Chamber, Cycler
from protocols.errors import InputError

log = logging.getLogger("battlab.lab")

VIRTUAL = "virtual"
#: link timeout on an accelerated clock, in virtual seconds, and at most this many real seconds: a reply lost on a
#: 1x bench costs one such wait and a retry, and a dead instrument stops the run within a second (a URL's own
#: ``timeout=`` option wins)
LINK_TIMEOUT_VIRTUAL_S = 15.0
REAL_LINK_TIMEOUT_S = 0.2
#: the shortest link timeout / real s: a loaded host (a few processes per core) delays a loopback reply by tens of
#: milliseconds, which must cost a marked gap in the log, not the run (15 virtual s at 1000x would be 15 ms)
MIN_LINK_TIMEOUT_S = 0.05
#: the drivers' own retries of a failed exchange during a run: none for the cycler (the engine retries, within its
#: time budget: :mod:`battlab.lab.calls`), one for the chamber (a Modbus transaction lost now and then)
CYCLER_RETRIES, CHAMBER_RETRIES = 0, 1


@dataclass(frozen=True)
class RunSettings:
    """Where and on what a plan runs (stored in the catalog, so a resume uses the same)."""

    cycler_url: str
    chamber_url: str
    cell: str = "nca18650"
    limits_path: str | None = None
    dialect: str | None = None
    #: the in-process virtual tester (``virtual`` URLs): speed, initial SOC, noise seed
    speed: float = 1000.0
    soc0: float | None = None
    seed: int = 0
    #: ``dfn`` (battlab's model, the default) or ``standin`` (the drivers' equivalent circuit: fast, for tests)
    physics: str = "dfn"
    #: the in-process virtual tester's clock: ``lockstep`` (the default: time moves only as the runner sleeps, so
    #: every sample is on time whatever the load; host and tester are one process, so a dead host is no case to
    #: test) or ``free`` (time runs by itself as on a real bench: late samples and the watchdog are possible)
    clock: str = "lockstep"
    library: str | None = None

    @property
    def virtual(self) -> bool:
        return VIRTUAL in (self.cycler_url.strip(), self.chamber_url.strip())

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> RunSettings:
        known = set(cls.__dataclass_fields__)
        return cls(**{k: v for k, v in data.items() if k in known})


@dataclass
class Bench:
    """Opened instruments, the run clock, and the in-process virtual lab if any."""

    cycler: Cycler
    chamber: Chamber
    clock: Clock
    speed: float
    lab: Any = None

    def close(self) -> None:
        for dev in (self.cycler, self.chamber):
            try:
                dev.close()
            except Exception as exc:  # closing must not hide the run's outcome
                log.warning("closing %s: %s", dev.name, exc)
        if self.lab is not None:
            self.lab.stop()


def resolve_limits(settings: RunSettings) -> InstrumentLimits:
    """The limits file, else the built-in virtual-tester limits (only for battlab's virtual dialect)."""
    if settings.limits_path:
        return InstrumentLimits.load(settings.limits_path)
    if dialect_name(settings, None) == VIRTUAL_LIMITS.cycler.dialect:
        return VIRTUAL_LIMITS
    raise InputError(
        f"cycler dialect {dialect_name(settings, None)!r}: a real instrument needs its limits file (--limits FILE)"
    )


def dialect_name(settings: RunSettings, limits: InstrumentLimits | None) -> str:
    if settings.dialect:
        return settings.dialect
    if limits is not None and limits.cycler.dialect:
        return limits.cycler.dialect
    return "battlab-virtual"


def open_bench(settings: RunSettings, cell: Any, limits: InstrumentLimits, ambient_degC: float) -> Bench:
    """Connect the instruments; ``virtual`` URLs start an in-process virtual tester with the cell's DFN physics."""
    from drivers.factory import open_chamber, open_cycler
    from drivers.scpi.dialects import dialect_by_name

    dialect = dialect_by_name(dialect_name(settings, limits))
    cycler_url, chamber_url, lab = settings.cycler_url.strip(), settings.chamber_url.strip(), None
    if settings.virtual:
        from battlab.lab.virtual import make_cell_physics
        from drivers.virtual.instruments import ChamberConfig
        from drivers.virtual.lab import CLOCK_MODES, VirtualLab, VirtualLabConfig
        from drivers.virtual.physics import EquivalentCircuitCell

        if settings.physics not in ("dfn", "standin"):
            raise InputError(f"virtual tester physics {settings.physics!r}: expected 'dfn' or 'standin'")
        if settings.clock not in CLOCK_MODES:
            raise InputError(f"virtual tester clock {settings.clock!r}: expected {' or '.join(map(repr, CLOCK_MODES))}")

        config = VirtualLabConfig(
            speed=settings.speed,
            soc0=0.5 if settings.soc0 is None else settings.soc0,
            seed=settings.seed,
            dialect=dialect,
            modbus_rtu_port=None,
            espec_port=None,
            chamber=ChamberConfig(T0_K=ambient_degC + 273.15),
            clock=settings.clock,
        )
        physics = make_cell_physics(cell) if settings.physics == "dfn" else EquivalentCircuitCell()
        lab = VirtualLab(physics, config).start()
        cycler_url = lab.cycler_url if cycler_url == VIRTUAL else cycler_url
        chamber_url = lab.chamber_url if chamber_url == VIRTUAL else chamber_url
    cycler: Cycler | None = None
    try:
        try:
            cycler = open_cycler(cycler_url, dialect=dialect, retries=CYCLER_RETRIES)
        except (InstrumentError, OSError) as exc:
            raise InputError(f"cycler {settings.cycler_url}: {_detail(exc)}") from None
        caps = cycler.capabilities
        try:  # a cycler without a clock of its own is timed by the host's
            clock: Clock = cycler.clock() if caps.clock else RealClock()
        except (InstrumentError, OSError) as exc:
            raise InputError(f"cycler {settings.cycler_url}: does not answer: {_detail(exc)}") from None
        if lab is not None and lab.clock.lockstep and cycler_url == lab.cycler_url:
            clock = lab.clock  # the runner's sleeps are what moves a lock-step tester's time
        speed = float(clock.speed)
        link_timeout = min(REAL_LINK_TIMEOUT_S, max(MIN_LINK_TIMEOUT_S, LINK_TIMEOUT_VIRTUAL_S / speed))
        if not _has_timeout(cycler_url) and caps.link_timeout:
            cycler.link_timeout_s = link_timeout  # the link timeout follows the instrument's clock
        # RTU framing paces frames by the baud rate (~40 ms for a 15-register reply at 9600 baud)
        floor = 0.25 if chamber_url.startswith("modbus-rtu") else 0.05
        try:
            chamber = open_chamber(
                chamber_url,
                timeout_s=None if _has_timeout(chamber_url) else max(floor, link_timeout),
                retries=CHAMBER_RETRIES,
            )
        except (InstrumentError, OSError) as exc:
            raise InputError(f"chamber {settings.chamber_url}: cannot connect: {_detail(exc)}") from None
    except BaseException:
        if cycler is not None:
            cycler.close()
        if lab is not None:
            lab.stop()
        raise
    return Bench(cycler, chamber, clock, speed, lab)


def connect_bench(settings: RunSettings, cell: Any, limits: InstrumentLimits, ambient_degC: float) -> Bench:
    """:func:`open_bench`, then each instrument asked for its identity: an instrument that cannot be reached or
    does not answer is an :class:`InputError` naming it, its URL and what failed (nothing has started yet)."""
    bench = open_bench(settings, cell, limits, ambient_degC)
    try:
        for role, url, device in (
            ("cycler", settings.cycler_url, bench.cycler),
            ("chamber", settings.chamber_url, bench.chamber),
        ):
            try:
                device.identify()
            except (InstrumentError, OSError) as exc:
                raise InputError(f"{role} {url}: does not answer: {_detail(exc)}") from None
    except BaseException:
        bench.close()
        raise
    return bench


def _detail(exc: BaseException) -> str:
    """What an instrument error says, without the instrument's name (the caller names it)."""
    return " ".join(str(getattr(exc, "detail", exc)).split())


def _has_timeout(url: str) -> bool:
    """The URL sets its own link timeout (``?timeout=SECONDS``)."""
    from drivers.urls import parse_url

    return url.strip() != VIRTUAL and parse_url(url).option("timeout") is not None


def watchdog_for(speed: float) -> float:
    """Instrument watchdog / s of the instrument's clock: 60 s, and at least 0.5 s of real time (longer than a
    chamber exchange that times out, during which the cycler hears nothing)."""
    return max(60.0, 0.5 * speed)


__all__ = [
    "Bench",
    "CHAMBER_RETRIES",
    "CYCLER_RETRIES",
    "LINK_TIMEOUT_VIRTUAL_S",
    "MIN_LINK_TIMEOUT_S",
    "REAL_LINK_TIMEOUT_S",
    "RunSettings",
    "VIRTUAL",
    "connect_bench",
    "dialect_name",
    "open_bench",
    "resolve_limits",
    "watchdog_for",
]
