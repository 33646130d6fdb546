"""The runner's policy for instrument calls: bounded retries with doubling back-off on link errors, a resync of
the link before a retry, instrument errors and faults turned into an :class:`~battlab.lab.run_state.Abort`, and
settings a dialect lacks noted rather than fatal."""

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


class InstrumentCalls:
    """Makes instrument calls for the engine; ``timing`` counts their wall time into ``stats.io_wall_s``."""

    def __init__(self, retries: int, backoff_s: float, clock: Clock, stats: RunStats) -> None:
        self.retries = retries
        self.backoff_s = backoff_s
        self.clock = clock
        self.stats = stats
        self.timing = False

    def call(self, what: str, fn: Callable[..., T], *args: Any) -> T:
        """An instrument call with bounded retries (doubling back-off on the run clock) on link errors."""
        delay = self.backoff_s
        w0 = time.perf_counter() if self.timing else None
        try:
            for attempt in range(self.retries + 1):
                try:
                    return fn(*args)
                except CommunicationError as exc:
                    if attempt == self.retries:
                        raise Abort("communication", f"{what} failed after {attempt + 1} attempts: {exc}") from exc
                    self.stats.retries += 1
                    log.warning("%s failed (%s); retry %d in %g s", what, exc, attempt + 1, delay)
                    resync(fn)
                    self.clock.sleep(delay)
                    delay *= 2
                except InstrumentFault as exc:
                    raise Abort("instrument", f"{what}: {exc}") from exc
                except InstrumentError as exc:
                    raise Abort("instrument", f"{what}: {exc}") from exc
            raise AssertionError("unreachable")
        finally:
            if w0 is not None:
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
            log.warning("link resync failed: %s", exc)
