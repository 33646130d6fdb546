"""The run log's columns, and reopening an interrupted log for a resume.

A log left by a killed runner is readable (SWMR: :func:`battlab.io.logs.read_log`) but cannot be reopened for
writing (HDF5 marks it still open; only ``h5clear`` would reset that). :func:`reopen` therefore keeps it as a
backup (``run.interrupted-1.h5``), writes a fresh log at the same path with the same columns, copies every
recovered row into it and flushes, then the run continues appending. :func:`drop_backups` removes the backups
once the log has been closed cleanly and holds at least their rows. Nothing is deleted before that.

A copy that cannot be read at all (a runner killed as it created the log leaves HDF5's 48-byte superblock alone; a
truncated or damaged file) is moved aside by :func:`set_aside_unreadable` to ``run.unreadable-1.h5``: kept for
inspection, never taken for a backup again, never deleted.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from battlab.io.data import AMBIENT, CURRENT, NET_CAPACITY, STEP, SURFACE, TIME, VOLTAGE, LoggedData
from battlab.io.logged import CYCLE, STEP_INDEX
from battlab.io.logs import LogWriter, open_log, read_log
from protocols.errors import InputError

log = logging.getLogger("battlab.lab")

UNIX_TIME = "Unix Time / s"
STEP_TIME = "Step Time / s"

#: the runner's columns (BDF names); Step Count counts step executions (a restarted step gets a new count),
#: Step Index is the step's 1-based position in the plan, Cycle Count the trial of a repeated profile, Net Capacity
#: the charge passed since the run's start (not counted across an interruption)
COLUMNS: tuple[str, ...] = (
    TIME,
    UNIX_TIME,
    STEP_TIME,
    VOLTAGE,
    CURRENT,
    SURFACE,
    AMBIENT,
    STEP,
    STEP_INDEX,
    CYCLE,
    NET_CAPACITY,
)


def create(path: str | Path, columns: Sequence[str], meta: Mapping[str, Any]) -> LogWriter:
    """A new run log (an existing file is an error: logs are never overwritten); readable from its first flush, its
    metadata completed until then (the run's origin is known only at the first step's start)."""
    return open_log(path, list(columns), dict(meta), chunk_rows=4096, defer_swmr=True)


def backups(path: str | Path, kind: str = "interrupted") -> list[Path]:
    """Backups of interrupted logs of ``path`` (``kind="unreadable"``: the copies set aside), oldest first."""
    path = Path(path)
    found = []
    for p in path.parent.glob(f"{path.stem}.{kind}-*{path.suffix}"):
        tag = p.name[len(path.stem) + len(kind) + 2 : len(p.name) - len(path.suffix)]
        if tag.isdigit():
            found.append((int(tag), p))
    return [p for _, p in sorted(found)]


def _free_name(path: Path, kind: str) -> Path:
    """``<stem>.<kind>-N<suffix>`` beside ``path`` with the first N not yet taken."""
    n = len(backups(path, kind)) + 1
    target = path.with_name(f"{path.stem}.{kind}-{n}{path.suffix}")
    while target.exists():
        n += 1
        target = path.with_name(f"{path.stem}.{kind}-{n}{path.suffix}")
    return target


def set_aside_unreadable(path: str | Path) -> list[tuple[Path, Path, str]]:
    """Move every copy of the log at ``path`` (itself and its backups) that cannot be read to
    ``<stem>.unreadable-N<suffix>``; returns (old path, new path, why) for each."""
    path = Path(path)
    moved = []
    for candidate in [*backups(path), path]:
        if not candidate.is_file():
            continue
        try:
            read_log(candidate)
        except InputError as exc:
            target = _free_name(path, "unreadable")
            os.replace(candidate, target)
            moved.append((candidate, target, str(exc)))
    return moved


def recover(path: str | Path) -> LoggedData | None:
    """The most complete readable copy of an interrupted log: ``path`` or one of its backups (None: nothing)."""
    best: LoggedData | None = None
    for candidate in [*backups(path), Path(path)]:
        if not candidate.is_file():
            continue
        try:
            data = read_log(candidate)
        except InputError as exc:
            log.warning("resume: %s is not readable (%s)", candidate, exc)
            continue
        if best is None or len(data) >= len(best):
            best = data
    return best


def reopen(path: str | Path, meta: Mapping[str, Any]) -> tuple[LogWriter, LoggedData | None]:
    """A writable log at ``path`` holding every row recovered from the interrupted one (see the module doc).

    Returns the writer (rows copied and flushed) and the recovered data (None if there was no log yet).
    """
    path = Path(path)
    old = recover(path)
    if path.exists():
        target = _free_name(path, "interrupted")
        os.replace(path, target)
        log.info("resume: kept the interrupted log as %s", target)
    columns = list(COLUMNS)
    if old is not None and list(old.columns) != columns:
        raise InputError(f"{path}: its columns {list(old.columns)} are not this runner's {columns}; cannot resume")
    writer = create(path, columns, meta)
    if old is not None and len(old):
        writer.append(np.column_stack([old.columns[c] for c in columns]))
        writer.mark_gaps(old.meta.get("gaps", []))
        writer.flush()
    return writer, old


def drop_backups(path: str | Path) -> list[Path]:
    """Remove the backups of a cleanly closed log that holds at least as many rows as each; returns them."""
    path = Path(path)
    data = read_log(path)
    if not data.meta.get("complete"):
        return []
    removed = []
    for b in backups(path):
        try:
            n = len(read_log(b))
        except InputError:
            continue
        if n <= len(data):
            b.unlink()
            removed.append(b)
    return removed


__all__ = [
    "COLUMNS",
    "CYCLE",
    "STEP_INDEX",
    "STEP_TIME",
    "UNIX_TIME",
    "backups",
    "create",
    "drop_backups",
    "recover",
    "reopen",
    "set_aside_unreadable",
]
