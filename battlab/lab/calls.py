"""The runner's policy for instrument calls: bounded retries on link errors, a resync of the link before a retry,
instrument errors and faults turned into an :class:`~battlab.lab.run_state.Abort`, and settings a dialect lacks
noted rather than fatal.

Retries are bounded twice: by count (``retries``) and by real time (``budget_s``, from the call's start), so that a
dead instrument stops the run within about a second at any clock speed while a short blip (a lost reply, a dropped
connection) is retried. The back-off doubles from ``backoff_s`` of the run clock, at most ``MAX_BACKOFF_S`` real
seconds: on a 1x clock a plan's 0.5 s first back-off would eat the whole budget.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any, TypeVar

from battlab.lab.run_state import Abort, RunStats
from drivers.clock import Clock
from drivers.errors import CommunicationError, InstrumentError, InstrumentFault
from protocols.errors import InputError

log = logging.getLogger("battlab.lab")
T = TypeVar("T")

#: real seconds a failing call may take, its attempts, resyncs and back-offs together, before the run aborts
BUDGET_S = 0.4
#: the longest back-off between two attempts / real s
MAX_BACKOFF_S = 0.02


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
                    return fn(*args)
                except CommunicationError as exc:
                    elapsed = time.perf_counter() - w0
                    if attempt == self.retries or elapsed + delay > self.budget_s:
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
