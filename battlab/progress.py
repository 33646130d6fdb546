"""Progress as documents to subscribers: long work reports ``ProgressEvent``s and never draws anything itself.

A workflow function takes ``subscribers`` (callables of one event); the command line passes :class:`RichBar`,
a notebook may pass its own, tests pass none.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class ProgressEvent:
    """``kind``: ``start`` (``total`` known), ``advance`` (``done`` of ``total``, a short ``text``) or ``stop``."""

    task: str
    kind: str
    done: int = 0
    total: int = 0
    text: str = ""


Subscriber = Callable[[ProgressEvent], None]


def emit(subscribers: Sequence[Subscriber], event: ProgressEvent) -> None:
    for s in subscribers:
        s(event)


class RichBar:
    """A rich progress bar on stderr, one per task."""

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
        elif ev.kind == "stop" and ev.task in self._bars:
            bar, _ = self._bars.pop(ev.task)
            bar.stop()  # type: ignore[attr-defined]
