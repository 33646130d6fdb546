"""Starting and resuming runs: plan, cell, limits and pre-flight; the run lock and the instruments connected and
answering (:mod:`battlab.lab.bench`) before anything is recorded; catalog record, log and display wired to a
:class:`~battlab.lab.engine.RunEngine`; Ctrl-C as a safe stop.

``battlab run`` and ``battlab runs resume`` are thin shells over :func:`start_run` and :func:`resume_run`.
"""

from __future__ import annotations

import logging
import signal
import threading
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from battlab.io.data import NET_CAPACITY
from battlab.io.plan import DESIGN_GROUPS, summary_groups
from battlab.lab import logfile
from battlab.lab.bench import (
    VIRTUAL,
    Bench,
    RunSettings,
    connect_bench,
    dialect_name,
    open_bench,
    resolve_limits,
    watchdog_for,
)
from battlab.lab.catalog import Catalog, RunLock, RunRecord
from battlab.lab.documents import CatalogSink, LogSink, Subscriber
from battlab.lab.engine import EngineConfig, RunEngine, RunState
from battlab.lab.limits import CellWindow, InstrumentLimits
from battlab.lab.plan import Plan
from battlab.lab.preflight import check_plan
from battlab.lab.progress import ProgressDisplay
from protocols.errors import InputError

log = logging.getLogger("battlab.lab")


@dataclass
class RunResult:
    run_id: int
    status: str
    reason: str | None
    log_path: Path
    summary: dict[str, Any] = field(default_factory=dict)


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


def _window_check(plan: Plan, cell: Any, settings: RunSettings) -> Callable[[float], None] | None:
    """The plan's SOC and voltage window on ``cell`` (:mod:`battlab.lab.window`), checked now when the plan's start
    state is known (it charges the cell before its first profile; ``--soc0``; the in-process virtual cell's SOC);
    else returned as a check of the rest voltage that the preflight measures before any output is switched on."""
    from battlab.lab.window import check_window, needs_start_soc

    where = plan.source or plan.protocol.name
    ambient = plan.options.ambient_degC + 273.15
    if not needs_start_soc(plan.protocol, cell):
        check_window(plan.protocol, cell, ambient_K=ambient).raise_if_bad(where)
        return None
    if settings.soc0 is not None or settings.virtual:
        soc = 0.5 if settings.soc0 is None else settings.soc0
        how = f"start SOC {soc:g} ({'--soc0' if settings.soc0 is not None else 'the virtual cell'})"
        check_window(plan.protocol, cell, start_soc=soc, start=how, ambient_K=ambient).raise_if_bad(where)
        return None

    def at_rest(voltage: float) -> None:
        lo, hi = float(cell.ocv(0.0)), float(cell.ocv(1.0))
        soc = cell.soc_from_voltage(min(max(voltage, lo), hi))
        how = f"SOC {soc:.3f} (the rest voltage {voltage:.4f} V)"
        check_window(plan.protocol, cell, start_soc=soc, start=how, ambient_K=ambient).raise_if_bad(where)

    return at_rest


@dataclass
class _Connected:
    """A run's lock held, its plan checked, its instruments connected and answering."""

    bench: Bench
    cell: Any
    limits: InstrumentLimits
    envelope: Any
    #: the plan's window check at the measured rest voltage (None: checked before connecting, or a resume)
    window_check: Callable[[float], None] | None = None


@contextmanager
def _connected(plan: Plan, settings: RunSettings, log_path: Path, *, new_run: bool = False) -> Iterator[_Connected]:
    """The run lock on ``log_path``, then the bench connected (:func:`connect_bench`); both released on exit. Any
    failure here is before the run: the caller has recorded nothing yet. A ``new_run`` has its plan's window
    checked (:func:`_window_check`) first."""
    cell, limits, envelope = _prepare(plan, settings)
    window_check = _window_check(plan, cell, settings) if new_run else None
    lock = RunLock(log_path)
    lock.acquire()
    try:
        bench = connect_bench(settings, cell, limits, plan.options.ambient_degC)
        try:
            yield _Connected(bench, cell, limits, envelope, window_check)
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
        window_check=connected.window_check,
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
    with _connected(plan, settings, log_path, new_run=True) as connected:
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
    groups = _design_groups(plan_path)
    if groups is not None:
        meta[DESIGN_GROUPS] = [g.to_dict() for g in groups]
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


def _design_groups(plan_path: str | None) -> list[Any] | None:
    """The groups of the design summary beside the plan file (None: no file, or no summary): kept in the log so
    that ``battlab fit`` of the log alone fits the design's groups in stages."""
    if plan_path is None:
        return None
    try:
        return summary_groups(plan_path)
    except InputError as exc:  # a damaged summary does not stop a run; the fit then needs --plan
        log.warning("run: the plan's design groups are not kept in the log (%s)", exc)
        return None


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


# the bench's names, kept importable from here
__all__ = [
    "VIRTUAL",
    "Bench",
    "RunResult",
    "RunSettings",
    "connect_bench",
    "dialect_name",
    "open_bench",
    "resolve_limits",
    "resume_run",
    "start_run",
    "watchdog_for",
]
