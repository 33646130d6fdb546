"""Running the sweep: which profiles, on local worker processes or a Dask cluster, with progress to a callback."""

from __future__ import annotations

import contextlib
import json
import os
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from battlab.cell import Cell
from battlab.design.sweep.keys import CONVENTIONAL, GROUP, SweepConfig, model_source_hash, profile_hash, result_key
from battlab.design.sweep.store import SensitivityStore, group_name
from battlab.design.sweep.task import Outcome, Task, run_task
from battlab.progress import ProgressEvent, RichBar, Subscriber, emit
from protocols.errors import InputError
from protocols.profile import Profile

# --- the sweep ---------------------------------------------------------------------------------------------


@dataclass
class SweepReport:
    """Counts and timing of a sweep (``computed`` this run, ``reused`` from the store)."""

    path: Path
    total: int = 0
    reused: int = 0
    computed: int = 0
    ok: int = 0
    flagged: int = 0
    failed: int = 0
    wall_seconds: float = 0.0
    cpu_seconds: float = 0.0
    failures: dict[Any, str] = field(default_factory=dict)
    flags: dict[Any, str] = field(default_factory=dict)


Executor = Callable[[Sequence[Task]], Iterator[Outcome]]


def local_executor(workers: int) -> Executor:
    """Run tasks on ``workers`` local processes (1: in this process), at most a few in flight per worker so that
    memory stays bounded (results are written and dropped as they arrive)."""

    def run(tasks: Sequence[Task]) -> Iterator[Outcome]:
        if workers <= 1:
            for task in tasks:
                yield run_task(task)
            return
        import multiprocessing as mp

        with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("forkserver")) as pool:
            yield from _windowed(pool.submit, tasks, 3 * workers, wait_any=_wait_local)

    return run


def _wait_local(pending: set) -> tuple[set, set]:
    from concurrent.futures import FIRST_COMPLETED, wait

    done, rest = wait(pending, return_when=FIRST_COMPLETED)
    return set(done), set(rest)


def _windowed(submit: Callable[..., Any], tasks: Sequence[Task], window: int, wait_any: Callable) -> Iterator[Outcome]:
    """Submit ``tasks`` in order keeping at most ``window`` in flight; yield outcomes as they complete."""
    it = iter(tasks)
    pending: dict[Any, Task] = {}
    for task in it:
        pending[submit(run_task, task)] = task
        if len(pending) >= window:
            break
    while pending:
        done, _ = wait_any(set(pending))
        for fut in done:
            task = pending.pop(fut)
            yield _outcome_of(fut, task)
            nxt = next(it, None)
            if nxt is not None:
                pending[submit(run_task, nxt)] = nxt


def dask_executor(scheduler: str | Any, timeout_s: float = 10.0) -> Executor:
    """Run tasks on a Dask distributed cluster (a scheduler address like ``tcp://host:8786`` or a Client)."""

    def run(tasks: Sequence[Task]) -> Iterator[Outcome]:
        from dask.distributed import Client, wait

        own = not isinstance(scheduler, Client)
        try:
            client = Client(scheduler, timeout=f"{timeout_s}s") if own else scheduler
        except OSError as exc:
            raise InputError(f"cannot reach the Dask scheduler at {scheduler}: {exc}") from None
        try:
            n = max(sum(client.nthreads().values()), 1)

            def submit(fn: Callable, task: Task) -> Any:
                return client.submit(fn, task, pure=False, key=f"battlab-sweep-{task.key[:16]}-{task.pid}")

            def wait_any(pending: set) -> tuple[set, set]:
                res = wait(list(pending), return_when="FIRST_COMPLETED")
                return set(res.done), set(res.not_done)

            yield from _windowed(submit, tasks, 3 * n, wait_any=wait_any)
        finally:
            if own:
                client.close()

    return run


def _outcome_of(fut: Any, task: Task) -> Outcome:
    try:
        return fut.result()
    except Exception as exc:  # the worker died or the task could not be shipped: record, do not drop
        return Outcome(task.pid, task.key, "failed", f"worker error: {type(exc).__name__}: {exc}")


def select_profiles(
    profiles: Iterable[Profile], ids: Sequence[int] | None = None, limit: int | None = None
) -> list[Profile]:
    """The profiles to sweep: those with the given ids (all if None), then the first ``limit``."""
    profs = list(profiles)
    if ids:
        have = {int(p.id): p for p in profs}  # type: ignore[arg-type]
        missing = [i for i in ids if int(i) not in have]
        if missing:
            raise InputError(f"no profile(s) with id {missing} in the library (ids run {min(have)}..{max(have)})")
        profs = [have[int(i)] for i in ids]
    if limit is not None:
        if limit < 1:
            raise InputError(f"--limit must be at least 1, got {limit}")
        profs = profs[:limit]
    return profs


def sweep(
    profiles: Iterable[Profile],
    cell: Cell,
    out: str | Path,
    *,
    config: SweepConfig | None = None,
    workers: int | None = None,
    scheduler: str | Any | None = None,
    conventional: Sequence[Profile] = (),
    conventional_rest_s: float = 3600.0,
    library_path: str | None = None,
    progress: bool = True,
    subscribers: Sequence[Subscriber] = (),
    on_written: Callable[[Outcome], None] | None = None,
    connect_timeout_s: float = 10.0,
) -> SweepReport:
    """Simulate every profile (and the conventional tests) with sensitivities into the store ``out``.

    Resumes: profiles whose stored key matches are reused; failed ones are retried. ``workers``: local
    processes (default: all cores); ``scheduler``: a Dask scheduler address or Client instead. ``on_written``
    is called after each profile is on disk (tests use it to kill the process mid-sweep). Progress goes to
    ``subscribers`` (``progress=True`` adds the console's bar).
    """
    t_wall = time.perf_counter()
    config = config or SweepConfig()
    profs = list(profiles)
    if not profs and not conventional:
        raise InputError("no profiles to sweep")
    for p in profs:
        if p.id is None or not str(p.id).isdigit():
            raise InputError(f"library profiles need integer ids, got {p.id!r}")
    store = SensitivityStore.create(out, cell, config, library_path=library_path)
    report = SweepReport(Path(out), total=len(profs) + len(conventional))
    try:
        src, ch, cd = model_source_hash(), cell.hash(), cell.to_toml_dict()
        tasks: list[tuple[Task, str, Profile]] = []
        for where, items, rest in ((GROUP, profs, 0.0), (CONVENTIONAL, list(conventional), conventional_rest_s)):
            for p in items:
                key = result_key(ch, profile_hash(p), config, src, rest)
                g = store.f[where].get(group_name(p.id))
                if g is not None and g.attrs["key"] == key and g.attrs["status"] != "failed":
                    report.reused += 1
                    continue
                tasks.append((Task.of(key, p, cd, config, rest), where, p))
        tasks.sort(key=lambda tw: -tw[0].duration - (1e6 if tw[1] == CONVENTIONAL else 0))  # longest first
        by_key = {(t.key, str(t.pid)): (w, p) for t, w, p in tasks}
        if tasks and scheduler is None:
            _warm(cell, config)
        ex = (
            dask_executor(scheduler, connect_timeout_s)
            if scheduler is not None
            else local_executor(workers or os.cpu_count() or 1)
        )
        subs = [*subscribers, *([RichBar()] if progress else [])]
        counts = {"ok": 0, "flagged": 0, "failed": 0}
        emit(subs, ProgressEvent("sensitivities", "start", 0, len(tasks), f"({report.reused} reused)"))
        try:
            for outcome in ex([t for t, _, _ in tasks]):
                where, prof = by_key[(outcome.key, str(outcome.id))]
                store.write(outcome, prof, where)
                report.computed += 1
                report.cpu_seconds += outcome.seconds
                if on_written is not None:
                    on_written(outcome)
                counts[outcome.status] = counts.get(outcome.status, 0) + 1
                text = (
                    f"ok {counts['ok']} flagged {counts['flagged']} failed {counts['failed']} ({report.reused} reused)"
                )
                emit(subs, ProgressEvent("sensitivities", "advance", report.computed, len(tasks), text))
        finally:
            emit(subs, ProgressEvent("sensitivities", "stop", report.computed, len(tasks)))
        for where in (GROUP, CONVENTIONAL):
            for pid, status in store.statuses(where).items():
                if where == GROUP and str(pid) not in {str(p.id) for p in profs}:
                    continue
                info = store.info(pid, where)
                if status == "ok":
                    report.ok += 1
                elif status == "flagged":
                    report.flagged += 1
                    report.flags[pid] = info["reason"]
                else:
                    report.failed += 1
                    report.failures[pid] = info["reason"]
        report.wall_seconds = time.perf_counter() - t_wall
        store.f.attrs["last_sweep"] = json.dumps(
            {
                k: v
                for k, v in asdict(report).items()
                if k in ("total", "reused", "computed", "ok", "flagged", "failed", "wall_seconds", "cpu_seconds")
            }
        )
        store.f.flush()
    finally:
        store.close()
    return report


def _warm(cell: Cell, config: SweepConfig) -> None:
    """Build (or load from the disk cache) the compiled stepper once before workers start, so they only load it."""
    from battlab.model import solver

    with contextlib.suppress(Exception):  # the workers then fall back to the CasADi stepper and say so
        solver.native_stepper(cell, config.mesh, config.isothermal)
