"""Work spread over this machine's cores with threads: the compiled stepper releases the GIL and keeps its work
memory per thread, so independent simulations and fits run side by side in one process (no pickling, one model
cache)."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")


def cores() -> int:
    """The cores this process may run on (its CPU affinity where the system tells it)."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1


def thread_map(fn: Callable[[T], R], items: Iterable[T], workers: int | None = None) -> list[R]:
    """``[fn(x) for x in items]``, in order, on up to ``workers`` threads (default: :func:`cores`); on the calling
    thread when one suffices. The first exception raised by ``fn`` is raised here."""
    xs = list(items)
    n = min(workers or cores(), len(xs))
    if n <= 1:
        return [fn(x) for x in xs]
    with ThreadPoolExecutor(n) as pool:
        return list(pool.map(fn, xs))
