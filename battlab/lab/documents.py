"""Documents the run engine emits, and the subscribers that consume them (bluesky's start → events → stop).

``start`` (:class:`RunStart`: columns and metadata) → ``origin`` (:class:`RunOrigin`: a new run's time origin, the
first step's start, sent just before its first event) → per step ``step_start`` / ``event`` rows (each after a gap
in sampling preceded by a ``gap`` document, :class:`Gap`) / ``step_stop`` → ``stop`` (:class:`RunStop`: status,
reason, summary). Subscribers are called in order; the log writer comes first, so a step is recorded complete in
the catalog only after its rows are flushed to disk.

Events are plain tuples in the order of ``RunStart.columns`` (no object per sample: the runner's overhead per
sample stays in microseconds).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from battlab.io.logged import TIME
from battlab.lab.catalog import Catalog
from battlab.lab.plan import PlanEntry

log = logging.getLogger("battlab.lab")


@dataclass(frozen=True)
class RunStart:
    run_id: int | None
    columns: tuple[str, ...]
    meta: dict[str, Any]


@dataclass(frozen=True)
class RunOrigin:
    """A new run's time origin: the instrument time / s of its first step's start (test time 0)."""

    t0_s: float


@dataclass(frozen=True)
class Gap:
    """Sampling stopped for longer than 1.5 sample periods: ``row`` is the row after the gap, ``t_from_s`` and
    ``t_to_s`` the test times / s of the samples either side."""

    row: int
    t_from_s: float
    t_to_s: float


@dataclass(frozen=True)
class StepStart:
    entry: PlanEntry
    step_count: int
    t_s: float
    row: int
    kind: str
    duration_s: float | None = None


@dataclass(frozen=True)
class StepStop:
    entry: PlanEntry
    step_count: int
    status: str  # completed | aborted | stopped
    ended_by: str | None
    t_s: float | None
    row: int


@dataclass(frozen=True)
class RunStop:
    status: str  # completed | aborted | stopped
    reason: str | None
    summary: dict[str, Any] = field(default_factory=dict)


class Subscriber:
    """A document consumer; override what you need."""

    def start(self, doc: RunStart) -> None: ...

    def origin(self, doc: RunOrigin) -> None: ...

    def gap(self, doc: Gap) -> None: ...

    def step_start(self, doc: StepStart) -> None: ...

    def event(self, row: tuple[float, ...]) -> None: ...

    def step_stop(self, doc: StepStop) -> None: ...

    def stop(self, doc: RunStop) -> None: ...


#: the log is flushed at least every this many seconds of test time (run clock), so a killed runner loses at most
#: about this much test time at any clock speed (plus a sample period)
FLUSH_TEST_S = 5.0


class LogSink(Subscriber):
    """Writes events and gap marks to the HDF5 run log: buffered, and flushed when ``flush_s`` real seconds or
    ``flush_test_s`` seconds of test time have passed since the last flush, whichever comes first, at every step end
    and at the stop. A killed runner loses at most the rows of the last ``min(flush_s × speed, flush_test_s)``
    seconds of test time.

    ``open_writer(columns, meta)`` creates the log when the start document arrives (the resume path copies the
    interrupted log first: :func:`battlab.lab.logfile.reopen`); the origin document completes its metadata
    (``t0_s``) before the first flush.
    """

    def __init__(self, open_writer: Any, flush_s: float = 1.0, flush_test_s: float = FLUSH_TEST_S) -> None:
        self._open_writer = open_writer
        self.flush_s = flush_s
        self.flush_test_s = flush_test_s
        self.writer: Any = None
        self._buffer: list[tuple[float, ...]] = []
        self._gaps: list[tuple[float, float, float]] = []
        self._last_flush = time.perf_counter()
        self._time_col = 0
        self._t_flushed: float | None = None  # test time / s of the last row flushed (at first: of the first row)
        self.flushes = 0
        self._written = 0

    @property
    def rows(self) -> int:
        """Rows in the log, flushed or buffered."""
        return self._written + len(self._buffer)

    def start(self, doc: RunStart) -> None:
        self.writer = self._open_writer(doc.columns, doc.meta)
        self._written = self.writer.n_rows
        self._time_col = doc.columns.index(TIME) if TIME in doc.columns else 0
        self._last_flush = time.perf_counter()

    def origin(self, doc: RunOrigin) -> None:
        if self.writer is not None:
            self.writer.update_meta({"t0_s": doc.t0_s})

    def gap(self, doc: Gap) -> None:
        self._gaps.append((float(doc.row), doc.t_from_s, doc.t_to_s))

    def event(self, row: tuple[float, ...]) -> None:
        self._buffer.append(row)
        t = row[self._time_col]
        if self._t_flushed is None:
            self._t_flushed = t
        if t - self._t_flushed >= self.flush_test_s or time.perf_counter() - self._last_flush >= self.flush_s:
            self.flush()

    def flush(self) -> None:
        if self.writer is None:
            return
        if self._buffer:
            self.writer.append(np.asarray(self._buffer, dtype=float))
            self._written += len(self._buffer)
            self._t_flushed = self._buffer[-1][self._time_col]
            self._buffer.clear()
        if self._gaps:
            self.writer.mark_gaps(self._gaps)
            self._gaps.clear()
        self.writer.flush()
        self.flushes += 1
        self._last_flush = time.perf_counter()

    def step_stop(self, doc: StepStop) -> None:
        self.flush()

    def stop(self, doc: RunStop) -> None:
        if self.writer is None:
            return
        self.flush()
        self.writer.close({"status": doc.status, "reason": doc.reason, **doc.summary})


class CatalogSink(Subscriber):
    """Records steps and the run's status in the catalog."""

    def __init__(self, catalog: Catalog, run_id: int, rows: Any) -> None:
        self.catalog = catalog
        self.run_id = run_id
        self._rows = rows  # callable: rows in the log now

    def start(self, doc: RunStart) -> None:
        self.catalog.update(self.run_id, t0=doc.meta.get("t0_s"))

    def origin(self, doc: RunOrigin) -> None:
        self.catalog.update(self.run_id, t0=doc.t0_s)

    def step_start(self, doc: StepStart) -> None:
        e = doc.entry
        self.catalog.step_started(
            self.run_id,
            step_count=doc.step_count,
            entry=e.entry,
            step_index=e.step_index,
            trial=e.trial,
            kind=doc.kind,
            label=e.label,
            t_start=doc.t_s,
            row_start=doc.row,
        )

    def step_stop(self, doc: StepStop) -> None:
        self.catalog.step_ended(
            self.run_id,
            step_count=doc.step_count,
            status=doc.status,
            ended_by=doc.ended_by,
            t_end=doc.t_s,
            row_end=doc.row,
            next_entry=doc.entry.entry + 1 if doc.status == "completed" else None,
        )

    def stop(self, doc: RunStop) -> None:
        self.catalog.update(self.run_id, status=doc.status, reason=doc.reason, rows=int(self._rows()))


class StepRecords(Subscriber):
    """The run's step records (for its summary and a resume), built from the step documents."""

    def __init__(self, previous: Sequence[dict[str, Any]] = ()) -> None:
        self.records: list[dict[str, Any]] = [dict(r) for r in previous]

    def step_start(self, doc: StepStart) -> None:
        e = doc.entry
        self.records.append(
            {
                "step_count": doc.step_count,
                "entry": e.entry,
                "step_index": e.step_index,
                "trial": e.trial,
                "kind": doc.kind,
                "label": e.label,
                "status": "running",
                "row_start": doc.row,
                "t_start": doc.t_s,
            }
        )

    def step_stop(self, doc: StepStop) -> None:
        for rec in reversed(self.records):
            if rec["step_count"] == doc.step_count:
                rec.update(status=doc.status, ended_by=doc.ended_by, row_end=doc.row, t_end=doc.t_s)
                return


def emit(subscribers: Sequence[Subscriber], name: str, doc: Any) -> None:
    """Deliver ``doc`` to every subscriber's ``name`` handler, in order."""
    for s in subscribers:
        getattr(s, name)(doc)


__all__ = [
    "CatalogSink",
    "FLUSH_TEST_S",
    "Gap",
    "LogSink",
    "RunOrigin",
    "RunStart",
    "RunStop",
    "StepStart",
    "StepRecords",
    "StepStop",
    "Subscriber",
    "emit",
]
