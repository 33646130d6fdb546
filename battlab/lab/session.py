"""Starting and resuming runs: plan, cell, limits and pre-flight; instruments (and the in-process virtual tester);
catalog record, run lock, log and display wired to a :class:`~battlab.lab.engine.RunEngine`; Ctrl-C as a safe stop.

``battlab run`` and ``battlab runs resume`` are thin shells over :func:`start_run` and :func:`resume_run`.
"""

from __future__ import annotations

import logging
import signal
import threading
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from battlab.io.data import NET_CAPACITY
from battlab.lab import logfile
from battlab.lab.catalog import Catalog, RunLock, RunRecord
from battlab.lab.documents import CatalogSink, LogSink, Subscriber
from battlab.lab.engine import EngineConfig, RunEngine, RunState
from battlab.lab.limits import VIRTUAL_LIMITS, CellWindow, InstrumentLimits
from battlab.lab.plan import Plan
from battlab.lab.preflight import check_plan
from battlab.lab.progress import ProgressDisplay
from drivers.clock import Clock, RealClock
from drivers.errors import InstrumentError
from drivers.interfaces import Chamber, Cycler
from protocols.errors import InputError

log = logging.getLogger("battlab.lab")

VIRTUAL = "virtual"
#: link timeout on an accelerated clock, in virtual seconds, and at most this many real seconds: a reply lost on a
#: 1x bench costs one such wait and a retry, and a dead instrument stops the run within about a second (a URL's own
#: ``timeout=`` option wins)
LINK_TIMEOUT_VIRTUAL_S = 15.0
REAL_LINK_TIMEOUT_S = 0.2
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
class RunResult:
    run_id: int
    status: str
    reason: str | None
    log_path: Path
    summary: dict[str, Any] = field(default_factory=dict)


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
                log.warning("closing %s: %s", getattr(dev, "name", dev), exc)
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
        from drivers.virtual.lab import VirtualLab, VirtualLabConfig
        from drivers.virtual.physics import EquivalentCircuitCell

        if settings.physics not in ("dfn", "standin"):
            raise InputError(f"virtual tester physics {settings.physics!r}: expected 'dfn' or 'standin'")

        config = VirtualLabConfig(
            speed=settings.speed,
            soc0=0.5 if settings.soc0 is None else settings.soc0,
            seed=settings.seed,
            dialect=dialect,
            modbus_rtu_port=None,
            espec_port=None,
            chamber=ChamberConfig(T0_K=ambient_degC + 273.15),
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
        try:
            clock: Clock = cycler.clock() if hasattr(cycler, "clock") else RealClock()
        except (InstrumentError, OSError) as exc:
            raise InputError(f"cycler {settings.cycler_url}: does not answer: {_detail(exc)}") from None
        speed = float(getattr(clock, "speed", 1.0))
        link_timeout = min(REAL_LINK_TIMEOUT_S, max(0.005, LINK_TIMEOUT_VIRTUAL_S / speed))
        adapter = getattr(cycler, "adapter", None)
        if not _has_timeout(cycler_url) and adapter is not None and hasattr(adapter, "timeout_s"):
            adapter.timeout_s = link_timeout  # the link timeout follows the instrument's clock
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


@contextmanager
def _safe_stop_signals(engine: RunEngine) -> Iterator[None]:
    """Ctrl-C / SIGTERM: a safe stop at the next tick; a second one, or one during a blocking wait, interrupts."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    presses = [0]

    def handler(signum: int, frame: object) -> None:
        presses[0] += 1
        engine.request_stop(f"stopped by the operator ({signal.Signals(signum).name})")
        if presses[0] > 1 or engine.state is not RunState.RUNNING:
            raise KeyboardInterrupt

    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def _prepare(plan: Plan, settings: RunSettings) -> tuple[Any, InstrumentLimits, Any]:
    from battlab.cell import Cell

    cell = Cell.load(settings.cell)
    limits = resolve_limits(settings)
    envelope = check_plan(plan, CellWindow.of(cell), limits)
    return cell, limits, envelope


@dataclass
class _Connected:
    """A run's lock held, its plan checked, its instruments connected and answering."""

    bench: Bench
    cell: Any
    limits: InstrumentLimits
    envelope: Any


@contextmanager
def _connected(plan: Plan, settings: RunSettings, log_path: Path) -> Iterator[_Connected]:
    """The run lock on ``log_path``, then the bench connected (:func:`connect_bench`); both released on exit. Any
    failure here is before the run: the caller has recorded nothing yet."""
    cell, limits, envelope = _prepare(plan, settings)
    lock = RunLock(log_path)
    lock.acquire()
    try:
        bench = connect_bench(settings, cell, limits, plan.options.ambient_degC)
        try:
            yield _Connected(bench, cell, limits, envelope)
        finally:
            bench.close()
    finally:
        lock.release()


def _execute(
    *,
    run_id: int,
    catalog: Catalog,
    plan: Plan,
    connected: _Connected,
    log_path: Path,
    open_writer: Callable[[Any, Any], Any],
    config_overrides: dict[str, Any],
    meta: dict[str, Any],
    display: bool,
    extra_subscribers: tuple[Subscriber, ...],
) -> RunResult:
    bench, limits = connected.bench, connected.limits
    watchdog = plan.options.watchdog_s or watchdog_for(bench.speed)
    config = EngineConfig(
        envelope=connected.envelope,
        clock=bench.clock,
        run_id=run_id,
        meta={**meta, "limits": limits.to_dict(), "clock_speed": bench.speed},
        watchdog_s=watchdog,
        safe_set_point_degC=limits.chamber.safe_set_point,
        soc_from_voltage=connected.cell.soc_from_voltage,
        **config_overrides,
    )
    sink = LogSink(open_writer, plan.options.flush_s)
    subscribers: list[Subscriber] = [sink, CatalogSink(catalog, run_id, lambda: sink.rows)]
    subscribers.append(ProgressDisplay(plan.protocol.name, len(plan.entries()), quiet=not display))
    subscribers.extend(extra_subscribers)
    engine = RunEngine(plan, bench.cycler, bench.chamber, config, subscribers)
    with _safe_stop_signals(engine):
        state = engine.run()
    summary = {"stats": engine.stats.to_dict(), "shutdown": engine.shutdown.to_dict() if engine.shutdown else None}
    if sink.writer is not None and state in (RunState.COMPLETED, RunState.ABORTED, RunState.STOPPED):
        for b in logfile.drop_backups(log_path):
            log.info("removed %s (its rows are in %s)", b, log_path)
    return RunResult(run_id, state.value, engine.reason, log_path, summary)


def start_run(
    plan: Plan | str | Path,
    settings: RunSettings,
    log_path: str | Path,
    *,
    catalog: Catalog | None = None,
    display: bool = True,
    extra_subscribers: tuple[Subscriber, ...] = (),
) -> RunResult:
    """Run a plan from its start; the run is recorded in the catalog and logged to ``log_path`` (a new file)."""
    plan_path = None
    if not isinstance(plan, Plan):
        plan_path = str(Path(plan).resolve())
        plan = Plan.load(plan, library=settings.library)
    log_path = Path(log_path).resolve()
    if log_path.exists():
        raise InputError(f"{log_path}: already exists; a run log is never overwritten")
    if not log_path.parent.is_dir():
        raise InputError(f"{log_path.parent}: no such directory for the run log")
    catalog = catalog or Catalog()
    # the plan checked and the instruments answering before the run is catalogued
    with _connected(plan, settings, log_path) as connected:
        return _start(plan, plan_path, settings, log_path, catalog, connected, display, extra_subscribers)


def _start(
    plan: Plan,
    plan_path: str | None,
    settings: RunSettings,
    log_path: Path,
    catalog: Catalog,
    connected: _Connected,
    display: bool,
    extra_subscribers: tuple[Subscriber, ...],
) -> RunResult:
    from battlab.io.logs import run_meta

    run_id = catalog.create(
        name=plan.protocol.name,
        plan=plan.to_dict(),
        plan_path=plan_path,
        log_path=str(log_path),
        settings=settings.to_dict(),
        n_entries=len(plan.entries()),
    )
    meta = run_meta(
        cell=connected.cell,
        plan=plan.to_dict(),
        instruments={
            "cycler": {"url": settings.cycler_url, "dialect": dialect_name(settings, None)},
            "chamber": {"url": settings.chamber_url},
        },
        run_id=run_id,
        settings=settings.to_dict(),
        soc0=settings.soc0,
        sample_period_s=plan.options.sample_period_s,
        resumes=[],
        interrupted=[],
    )
    return _execute(
        run_id=run_id,
        catalog=catalog,
        plan=plan,
        connected=connected,
        log_path=log_path,
        open_writer=lambda columns, m: logfile.create(log_path, columns, m),
        config_overrides={},
        meta=meta,
        display=display,
        extra_subscribers=extra_subscribers,
    )


def resume_run(
    run_id: int,
    *,
    catalog: Catalog | None = None,
    overrides: Mapping[str, Any] | None = None,
    display: bool = True,
    extra_subscribers: tuple[Subscriber, ...] = (),
) -> RunResult:
    """Resume an interrupted, aborted or stopped run from its first step not completed (restarted from its
    beginning); the log keeps every earlier row, and the rows of the interrupted attempt are marked in the log's
    metadata (``interrupted``: step count, rows, times)."""
    catalog = catalog or Catalog()
    rec = catalog.get(run_id)
    if rec.status == "completed":
        raise InputError(f"run {run_id} is completed; nothing to resume")
    if rec.live:
        raise InputError(f"run {run_id} is running (pid {rec.pid} on {rec.host})")
    settings = replace(RunSettings.from_dict(rec.settings), **dict(overrides or {}))
    plan = Plan.from_dict(rec.plan, source=f"run {run_id} (catalog)")
    log_path = Path(rec.log_path)
    # the plan checked and the instruments answering before anything changes
    previous_status = rec.shown_status  # read before this runner holds the run's lock
    with _connected(plan, settings, log_path) as connected:
        return _resume(rec, previous_status, catalog, plan, settings, log_path, connected, display, extra_subscribers)


def _resume(
    rec: RunRecord,
    previous_status: str,
    catalog: Catalog,
    plan: Plan,
    settings: RunSettings,
    log_path: Path,
    connected: _Connected,
    display: bool,
    extra_subscribers: tuple[Subscriber, ...],
) -> RunResult:
    run_id = rec.id
    unreadable = logfile.set_aside_unreadable(log_path)
    old = logfile.recover(log_path)
    n_old = len(old) if old is not None else 0
    if old is not None and list(old.columns) != list(logfile.COLUMNS):
        raise InputError(f"{log_path}: its columns are not this runner's {list(logfile.COLUMNS)}; cannot resume")
    start_entry = rec.next_entry if n_old else 0  # no rows kept: nothing of the run is on disk, start again
    for was, now, why in unreadable:
        then = "" if n_old else "; no data recovered: the run restarts from its first step"
        log.warning("resume: %s cannot be read (%s); kept aside as %s%s", was, why.removeprefix(f"{was}: "), now, then)
    last_tt = float(old.t[-1]) if old is not None and n_old else None
    catalog.mark_interrupted_steps(run_id, n_old)
    steps = catalog.steps(run_id)
    interrupted = []
    for s in steps:
        if s["status"] == "completed":
            continue
        a, b = s["row_start"], s["row_end"]
        t_span = [float(old.t[a]), float(old.t[b - 1])] if old is not None and a is not None and b > a else None
        interrupted.append(
            {
                "step_count": s["step_count"],
                "entry": s["entry"],
                "step_index": s["step_index"],
                "trial": s["trial"],
                "status": s["status"],
                "ended_by": s["ended_by"],
                "rows": [a, b],
                "test_time_s": t_span,
            }
        )
    base = {k: v for k, v in (old.meta if old is not None else {}).items() if k not in ("created", "complete", "final")}
    resume_note = {
        "resume": rec.resumes + 1,
        "row": n_old,
        "last_test_time_s": last_tt,
        "previous_status": previous_status,
        "previous_reason": rec.reason,
        "settings": settings.to_dict(),
    }
    if settings.virtual:
        resume_note["note"] = (
            f"in-process virtual tester restarted: its cell starts again at SOC "
            f"{0.5 if settings.soc0 is None else settings.soc0}, not where the run left it"
        )
        log.warning("resume: %s", resume_note["note"])
    meta = {**base, "resumes": [*base.get("resumes", []), resume_note], "interrupted": interrupted}
    if not base:
        meta.update(run_id=run_id, plan=rec.plan, settings=settings.to_dict())
    catalog.update(run_id, status="running", reason=None, resumes=rec.resumes + 1, settings=settings.to_dict())
    identities = base.get("identities") if not settings.virtual else None
    overrides_cfg = {
        "start_entry": start_entry,
        "step_count0": max([rec.step_count, *[s["step_count"] for s in steps]], default=0),
        "row0": n_old,
        "net_capacity0_Ah": float(old.columns[NET_CAPACITY][-1]) if old is not None and n_old else 0.0,
        "t0_s": rec.t0,
        "last_test_time_s": last_tt,
        "expected_identities": identities,
        "previous_steps": steps,
    }
    return _execute(
        run_id=run_id,
        catalog=catalog,
        plan=plan,
        connected=connected,
        log_path=log_path,
        open_writer=lambda columns, m: logfile.reopen(log_path, m)[0],
        config_overrides=overrides_cfg,
        meta=meta,
        display=display,
        extra_subscribers=extra_subscribers,
    )


__all__ = [
    "Bench",
    "connect_bench",
    "RunResult",
    "RunSettings",
    "open_bench",
    "resolve_limits",
    "resume_run",
    "start_run",
    "watchdog_for",
]
