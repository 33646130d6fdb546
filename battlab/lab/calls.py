"""The runner's policy for instrument calls: bounded retries on link errors, a resync of the link before a retry,
instrument errors and faults turned into an :class:`~battlab.lab.run_state.Abort`, and settings a dialect lacks
noted rather than fatal.

Retries are bounded twice: by count (``retries``) and by real time (``budget_s``, from the call's start), so that a
dead instrument stops the run within a second at any clock speed while a short blip (a lost reply, a dropped
connection) is retried. A retry's link timeout is cut to what is left of the budget (a healthy reply after a
reconnect takes milliseconds), so a call that keeps failing ends within the budget, not a full link timeout after
it. The back-off doubles from ``backoff_s`` of the run clock, at most ``MAX_BACKOFF_S`` real seconds: on a 1x clock
a plan's 0.5 s first back-off would eat the whole budget.
"""

from __future__ import annotations

import contextlib
import logging
import time
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

from battlab.lab.run_state import Abort, RunStats
from drivers.clock import Clock
from drivers.errors import CommunicationError, InstrumentError, InstrumentFault
from protocols.errors import InputError

log = logging.getLogger("battlab.lab")
T = TypeVar("T")

#: real seconds a failing call may take, its attempts, resyncs and back-offs together, before the run aborts: at 1x
#: (link timeout 0.2 s) a timed-out attempt, a dropped connection and a retry with the rest (over 0.05 s)
BUDGET_S = 0.35
#: the longest back-off between two attempts / real s
MAX_BACKOFF_S = 0.02
#: the shortest link timeout a retry is given / real s (a loaded host delays a loopback reply by tens of ms): with
#: less of the budget left the call fails without it
MIN_RETRY_TIMEOUT_S = 0.05


class InstrumentCalls:
    """Makes instrument calls for the engine; ``timing`` counts their wall time into ``stats.io_wall_s``."""

    def __init__(
        self, retries: int, backoff_s: float, clock: Clock, stats: RunStats, budget_s: float = BUDGET_S
    ) -> None:
        self.retries = retries
        self.backoff_s = backoff_s
        self.budget_s = budget_s
        self.clock = clock
        self.stats = stats
        self.timing = False

    def call(self, what: str, fn: Callable[..., T], *args: Any) -> T:
        """An instrument call, retried on link errors while both the count and the real-time budget allow."""
        w0 = time.perf_counter()
        speed = float(getattr(self.clock, "speed", 1.0))
        delay = min(self.backoff_s / speed, MAX_BACKOFF_S)
        try:
            for attempt in range(self.retries + 1):
                try:
                    if attempt == 0:
                        return fn(*args)
                    left = self.budget_s - (time.perf_counter() - w0)
                    with link_timeout_at_most(fn, max(left, MIN_RETRY_TIMEOUT_S)):
                        return fn(*args)
                except CommunicationError as exc:
                    elapsed = time.perf_counter() - w0
                    if attempt == self.retries or elapsed + delay + MIN_RETRY_TIMEOUT_S > self.budget_s:
                        raise Abort(
                            "communication",
                            f"{what} failed after {attempt + 1} attempts in {elapsed:.2f} s: {exc}",
                            device=getattr(fn, "__self__", None),
                        ) from exc
                    self.stats.retries += 1
                    log.info("%s failed (%s); retry %d in %.3g s", what, exc, attempt + 1, delay)
                    resync(fn)
                    time.sleep(delay)
                    delay = min(2 * delay, MAX_BACKOFF_S)
                except InstrumentFault as exc:
                    raise Abort("instrument", f"{what}: {exc}") from exc
                except InstrumentError as exc:
                    raise Abort("instrument", f"{what}: {exc}") from exc
            raise AssertionError("unreachable")
        finally:
            if self.timing:
                self.stats.io_wall_s += time.perf_counter() - w0

    def optional(self, what: str, fn: Callable[..., Any], *args: Any) -> bool:
        """A setting the dialect may not support (InputError): noted, not fatal."""
        try:
            self.call(what, fn, *args)
            return True
        except InputError as exc:
            self.stats.notes.append(f"{what}: not available ({exc}); runner-side checks only")
            log.warning("%s: not available: %s", what, exc)
            return False


@contextlib.contextmanager
def link_timeout_at_most(fn: Callable[..., Any], timeout_s: float) -> Iterator[None]:
    """The link timeout of ``fn``'s instrument (its adapter's ``timeout_s``, where it has one) at most ``timeout_s``
    for the duration."""
    adapter = getattr(getattr(fn, "__self__", None), "adapter", None)
    old = getattr(adapter, "timeout_s", None)
    if not isinstance(old, float) or old <= timeout_s:
        yield
        return
    adapter.timeout_s = timeout_s  # type: ignore[union-attr]
    try:
        yield
    finally:
        adapter.timeout_s = old  # type: ignore[union-attr]


def resync(fn: Callable[..., Any]) -> None:
    """After the driver gave up on an exchange, drop a late reply still on its way (reconnect the link) so that
    the retry does not read it as its own."""
    adapter = getattr(getattr(fn, "__self__", None), "adapter", None)
    recover = getattr(adapter, "recover", None)
    if callable(recover):
        try:
            recover()
        except (InstrumentError, OSError) as exc:
            log.info("link resync failed: %s", exc)
