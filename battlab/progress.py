"""Progress as events to subscribers: the one protocol every long piece of work reports through (the sweep, the
design, the fit, the diagnosis, the campaign's stages, runs on the lab). Work emits :class:`ProgressEvent` values
and never draws anything itself; the command line subscribes a display, a notebook its own, tests a list.

``kind``: ``start`` (``total`` known), ``advance`` (``done`` of ``total``, a short ``text``), ``note`` (a line worth
showing: a stage's result, a warning), ``stop``, ``skipped`` or ``failed``. ``payload`` carries the result an event
is about (a finished fit stage, the equilibrium fit, a campaign stage's record) for subscribers that render it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

KINDS = ("start", "advance", "note", "stop", "skipped", "failed")


@dataclass(frozen=True)
class ProgressEvent:
    """One progress document (see the module docstring)."""

    task: str
    kind: str
    done: float = 0
    total: float = 0
    text: str = ""
    payload: Any = None

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"progress event kind {self.kind!r}: expected one of {', '.join(KINDS)}")


Subscriber = Callable[[ProgressEvent], None]


def emit(subscribers: Sequence[Subscriber], event: ProgressEvent) -> None:
    for s in subscribers:
        s(event)


class Reporter:
    """Emits one task's events to ``subscribers``: ``start``, ``advance``, ``note``, ``stop`` with the task's name."""

    def __init__(self, task: str, subscribers: Sequence[Subscriber] = ()) -> None:
        self.task = task
        self.subscribers = tuple(subscribers)

    def __call__(self, kind: str, done: float = 0, total: float = 0, text: str = "", payload: Any = None) -> None:
        emit(self.subscribers, ProgressEvent(self.task, kind, done, total, text, payload))

    def child(self, task: str) -> Reporter:
        """A reporter of a sub-task (``"fit: stage 2"``) to the same subscribers."""
        return Reporter(f"{self.task}: {task}", self.subscribers)


def lines(echo: Callable[[str], None], *, tasks: Sequence[str] | None = None) -> Subscriber:
    """A subscriber that prints ``note`` events and each task's ``start``/``stop`` as lines (a log file, a pipe)."""

    def sub(ev: ProgressEvent) -> None:
        if tasks is not None and not any(ev.task.startswith(t) for t in tasks):
            return
        if ev.kind == "note" and ev.text:
            echo(ev.text)

    return sub


class RichBar:
    """A rich progress bar on stderr, one per task (``advance`` without a ``start`` is ignored)."""

    def __init__(self) -> None:
        self._bars: dict[str, tuple[object, object]] = {}

    def __call__(self, ev: ProgressEvent) -> None:
        from rich.console import Console
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        if ev.kind == "start":
            bar = Progress(
                TextColumn(ev.task),
                BarColumn(),
                MofNCompleteColumn(),
                TimeElapsedColumn(),
                TimeRemainingColumn(),
                TextColumn("{task.description}"),
                console=Console(stderr=True),
            )
            bar.start()
            self._bars[ev.task] = (bar, bar.add_task(ev.text, total=ev.total))
        elif ev.kind == "advance" and ev.task in self._bars:
            bar, task = self._bars[ev.task]
            bar.update(task, completed=ev.done, description=ev.text)  # type: ignore[attr-defined]
        elif ev.kind in ("stop", "failed") and ev.task in self._bars:
            bar, _ = self._bars.pop(ev.task)
            bar.stop()  # type: ignore[attr-defined]
