"""The run catalog: an embedded SQLite database of runs and their steps (``battlab runs list``).

Location: ``$BATTLAB_HOME/runs.sqlite``, else ``~/.local/share/battlab/runs.sqlite``. A run is ``running``,
``completed``, ``aborted`` (with its reason) or ``stopped`` (Ctrl-C); a ``running`` run whose runner died
(``kill -9``, power loss) shows as ``interrupted``: a live runner holds an exclusive lock on ``<log>.lock``
(:class:`RunLock`), which the operating system releases when the process dies.

The catalog stores what a resume needs: the plan as data (so editing the plan file does not change a run), the
instrument URLs and settings, the log path, the instrument time origin and the first plan entry not yet
completed. Steps are recorded as they start and end. Writes happen per step, never per sample.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import sqlite3
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from protocols.errors import InputError

STATUSES = ("running", "completed", "aborted", "stopped")

_SCHEMA = """
CREATE TABLE IF NOT EXISTS runs (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    created REAL NOT NULL,
    updated REAL NOT NULL,
    status TEXT NOT NULL,
    reason TEXT,
    name TEXT NOT NULL,
    plan_path TEXT,
    plan TEXT NOT NULL,
    log_path TEXT NOT NULL,
    settings TEXT NOT NULL,
    n_entries INTEGER NOT NULL,
    next_entry INTEGER NOT NULL DEFAULT 0,
    step_count INTEGER NOT NULL DEFAULT 0,
    rows INTEGER NOT NULL DEFAULT 0,
    t0 REAL,
    resumes INTEGER NOT NULL DEFAULT 0,
    pid INTEGER,
    host TEXT
);
CREATE TABLE IF NOT EXISTS steps (
    run_id INTEGER NOT NULL REFERENCES runs(id),
    step_count INTEGER NOT NULL,
    entry INTEGER NOT NULL,
    step_index INTEGER NOT NULL,
    trial INTEGER NOT NULL,
    kind TEXT NOT NULL,
    label TEXT,
    status TEXT NOT NULL,
    ended_by TEXT,
    t_start REAL,
    t_end REAL,
    row_start INTEGER,
    row_end INTEGER,
    PRIMARY KEY (run_id, step_count)
);
"""


def default_path() -> Path:
    """``$BATTLAB_HOME/runs.sqlite``, else ``~/.local/share/battlab/runs.sqlite``."""
    home = os.environ.get("BATTLAB_HOME")
    base = Path(home) if home else Path.home() / ".local" / "share" / "battlab"
    return base / "runs.sqlite"


@dataclass(frozen=True)
class RunRecord:
    """One row of the catalog."""

    id: int
    created: float
    updated: float
    status: str
    reason: str | None
    name: str
    plan_path: str | None
    plan: dict[str, Any]
    log_path: str
    settings: dict[str, Any]
    n_entries: int
    next_entry: int
    step_count: int
    rows: int
    t0: float | None
    resumes: int
    pid: int | None
    host: str | None

    @property
    def live(self) -> bool:
        """A runner holds this run's lock now."""
        return self.status == "running" and RunLock.held(self.log_path)

    @property
    def shown_status(self) -> str:
        """``interrupted`` for a running run without a live runner, else the stored status."""
        return "interrupted" if self.status == "running" and not self.live else self.status


class RunLock:
    """An exclusive ``flock`` on ``<log>.lock``, held by the runner of a run (released by the OS on death)."""

    def __init__(self, log_path: str | Path) -> None:
        self.path = Path(str(log_path) + ".lock")
        self._fd: int | None = None

    def acquire(self) -> None:
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            os.close(fd)
            raise InputError(f"{self.path}: another runner is running this log") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self._fd = fd

    def release(self) -> None:
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        with contextlib.suppress(OSError):
            fcntl.flock(fd, fcntl.LOCK_UN)
        os.close(fd)
        with contextlib.suppress(OSError):
            self.path.unlink()

    @staticmethod
    def held(log_path: str | Path) -> bool:
        path = Path(str(log_path) + ".lock")
        if not path.exists():
            return False
        try:
            fd = os.open(path, os.O_RDWR)
        except OSError:
            return False
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return True
        else:
            fcntl.flock(fd, fcntl.LOCK_UN)
            return False
        finally:
            os.close(fd)


class Catalog:
    """The run catalog at ``path`` (default :func:`default_path`)."""

    def __init__(self, path: str | Path | None = None) -> None:
        self.path = Path(path) if path is not None else default_path()
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._db: sqlite3.Connection | None = None
        self._lock = threading.Lock()
        try:
            with self._connect() as db:
                db.executescript(_SCHEMA)
        except sqlite3.DatabaseError as exc:
            raise InputError(f"{self.path}: not a usable run catalog ({exc})") from None

    @contextlib.contextmanager
    def _connect(self) -> Iterator[sqlite3.Connection]:
        """One connection per catalog object (a write costs well under a millisecond), one transaction per use."""
        with self._lock:
            if self._db is None:
                db = sqlite3.connect(self.path, timeout=10.0, check_same_thread=False)
                db.execute("PRAGMA journal_mode=WAL")
                db.execute("PRAGMA synchronous=NORMAL")
                self._db = db
            with self._db:
                yield self._db

    def close(self) -> None:
        with self._lock:
            if self._db is not None:
                self._db.close()
                self._db = None

    # -- runs --------------------------------------------------------------------------------------------
    def create(
        self,
        *,
        name: str,
        plan: dict[str, Any],
        plan_path: str | None,
        log_path: str,
        settings: dict[str, Any],
        n_entries: int,
    ) -> int:
        now = time.time()
        with self._connect() as db:
            cur = db.execute(
                "INSERT INTO runs (created, updated, status, name, plan_path, plan, log_path, settings, n_entries,"
                " pid, host) VALUES (?, ?, 'running', ?, ?, ?, ?, ?, ?, ?, ?)",
                (
                    now,
                    now,
                    name,
                    plan_path,
                    json.dumps(plan),
                    log_path,
                    json.dumps(settings),
                    n_entries,
                    os.getpid(),
                    socket.gethostname(),
                ),
            )
            assert cur.lastrowid is not None
            return int(cur.lastrowid)

    def update(self, run_id: int, **fields: Any) -> None:
        allowed = {
            "status",
            "reason",
            "next_entry",
            "step_count",
            "rows",
            "t0",
            "resumes",
            "pid",
            "host",
            "settings",
            "log_path",
        }
        bad = set(fields) - allowed
        if bad:
            raise ValueError(f"catalog: cannot update {sorted(bad)}")
        if "status" in fields and fields["status"] not in STATUSES:
            raise ValueError(f"catalog: unknown status {fields['status']!r}")
        if "settings" in fields:
            fields["settings"] = json.dumps(fields["settings"])
        cols = ", ".join(f"{k} = ?" for k in fields)
        with self._connect() as db:
            db.execute(f"UPDATE runs SET {cols}, updated = ? WHERE id = ?", (*fields.values(), time.time(), run_id))

    def get(self, run_id: int) -> RunRecord:
        with self._connect() as db:
            row = db.execute(f"SELECT {_COLUMNS} FROM runs WHERE id = ?", (run_id,)).fetchone()
        if row is None:
            raise InputError(f"run {run_id}: not in the run catalog {self.path}")
        return _record(row)

    def list(self, limit: int | None = None) -> list[RunRecord]:
        sql = f"SELECT {_COLUMNS} FROM runs ORDER BY id DESC"
        with self._connect() as db:
            rows = db.execute(sql + (" LIMIT ?" if limit else ""), (limit,) if limit else ()).fetchall()
        return [_record(r) for r in rows]

    # -- steps -------------------------------------------------------------------------------------------
    def step_started(
        self,
        run_id: int,
        *,
        step_count: int,
        entry: int,
        step_index: int,
        trial: int,
        kind: str,
        label: str,
        t_start: float,
        row_start: int,
    ) -> None:
        with self._connect() as db:
            db.execute(
                "INSERT OR REPLACE INTO steps (run_id, step_count, entry, step_index, trial, kind, label, status,"
                " t_start, row_start) VALUES (?, ?, ?, ?, ?, ?, ?, 'running', ?, ?)",
                (run_id, step_count, entry, step_index, trial, kind, label, t_start, row_start),
            )
            db.execute("UPDATE runs SET step_count = ?, updated = ? WHERE id = ?", (step_count, time.time(), run_id))

    def step_ended(
        self,
        run_id: int,
        *,
        step_count: int,
        status: str,
        ended_by: str | None,
        t_end: float | None,
        row_end: int,
        next_entry: int | None = None,
    ) -> None:
        """Close a step record; ``next_entry`` (a completed step) moves the resume point, in the same transaction."""
        with self._connect() as db:
            db.execute(
                "UPDATE steps SET status = ?, ended_by = ?, t_end = ?, row_end = ? WHERE run_id = ? AND step_count = ?",
                (status, ended_by, t_end, row_end, run_id, step_count),
            )
            if next_entry is not None:
                db.execute(
                    "UPDATE runs SET next_entry = ?, rows = ?, updated = ? WHERE id = ?",
                    (next_entry, row_end, time.time(), run_id),
                )

    def mark_interrupted_steps(self, run_id: int, rows: int) -> None:
        """Steps left ``running`` by a dead runner become ``interrupted``, ending at ``rows`` (the rows recovered
        from its log); a recorded end beyond that is cut to it."""
        with self._connect() as db:
            db.execute(
                "UPDATE steps SET status = 'interrupted', row_end = ? WHERE run_id = ? AND status = 'running'",
                (rows, run_id),
            )
            db.execute("UPDATE steps SET row_end = ? WHERE run_id = ? AND row_end > ?", (rows, run_id, rows))

    def steps(self, run_id: int) -> list[dict[str, Any]]:
        cols = (
            "step_count",
            "entry",
            "step_index",
            "trial",
            "kind",
            "label",
            "status",
            "ended_by",
            "t_start",
            "t_end",
            "row_start",
            "row_end",
        )
        with self._connect() as db:
            rows = db.execute(
                f"SELECT {', '.join(cols)} FROM steps WHERE run_id = ? ORDER BY step_count", (run_id,)
            ).fetchall()
        return [dict(zip(cols, r, strict=True)) for r in rows]


_COLUMNS = (
    "id, created, updated, status, reason, name, plan_path, plan, log_path, settings, n_entries, next_entry,"
    " step_count, rows, t0, resumes, pid, host"
)


def _record(row: tuple[Any, ...]) -> RunRecord:
    (
        rid,
        created,
        updated,
        status,
        reason,
        name,
        plan_path,
        plan,
        log_path,
        settings,
        n_entries,
        next_entry,
        step_count,
        rows,
        t0,
        resumes,
        pid,
        host,
    ) = row
    return RunRecord(
        int(rid),
        created,
        updated,
        status,
        reason,
        name,
        plan_path,
        json.loads(plan),
        log_path,
        json.loads(settings),
        n_entries,
        next_entry,
        step_count,
        rows,
        t0,
        resumes,
        pid,
        host,
    )


__all__ = ["Catalog", "RunLock", "RunRecord", "STATUSES", "default_path"]
