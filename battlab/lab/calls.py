"""The runner's policy for instrument calls: bounded retries on link errors, a resync of the link before a retry,
instrument errors and faults turned into an :class:`~battlab.lab.run_state.Abort`, and optional settings the
instrument refuses noted rather than fatal.

Retries are bounded twice: by count (``retries``) and by real time (``budget_s``, from the call's start), so that a
dead instrument stops the run within a second at any clock speed while a short blip (a lost reply, a dropped
connection) is retried. A retry's link timeout is cut to what is left of the budget (a healthy reply after a
reconnect takes milliseconds), so a call that keeps failing ends within the budget, not a full link timeout after
it. The back-off doubles from ``backoff_s`` of the run clock, at most ``MAX_BACKOFF_S`` real seconds: on a 1x clock
a plan's 0.5 s first back-off would eat the whole budget.
"""

from __future__ import annotations

import contextlib
import inspect
import logging
import time
from collections.abc import Callable, Iterator
from typing import Any, TypeVar

from battlab.lab.run_state import Abort, RunStats
from drivers.clock import Clock
from drivers.errors import CommunicationError, InstrumentError, InstrumentFault, NotSupported
from drivers.interfaces import Instrument
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
        delay = min(self.backoff_s / float(self.clock.speed), MAX_BACKOFF_S)
        device: Instrument | None = None  # found on the first link error (the healthy path does not look)
        try:
            for attempt in range(self.retries + 1):
                try:
                    if attempt == 0:
                        return fn(*args)
                    left = self.budget_s - (time.perf_counter() - w0)
                    with link_timeout_at_most(device, max(left, MIN_RETRY_TIMEOUT_S)):
                        return fn(*args)
                except CommunicationError as exc:
                    device = instrument_of(fn)
                    elapsed = time.perf_counter() - w0
                    if attempt == self.retries or elapsed + delay + MIN_RETRY_TIMEOUT_S > self.budget_s:
                        raise Abort(
                            "communication",
                            f"{what} failed after {attempt + 1} attempts in {elapsed:.2f} s: {exc}",
                            device=device,
                        ) from exc
                    self.stats.retries += 1
                    log.info("%s failed (%s); retry %d in %.3g s", what, exc, attempt + 1, delay)
                    resync(device)
                    time.sleep(delay)
                    delay = min(2 * delay, MAX_BACKOFF_S)
                except InstrumentFault as exc:
                    raise Abort("instrument", f"{what}: {exc}") from exc
                except InstrumentError as exc:
                    raise Abort("instrument", f"{what}: {exc}") from exc
                except NotSupported as exc:  # an operation called without asking the capabilities first
                    raise Abort("unsupported", f"{what}: {exc}") from exc
            raise AssertionError("unreachable")
        finally:
            if self.timing:
                self.stats.io_wall_s += time.perf_counter() - w0

    def optional(self, what: str, fn: Callable[..., Any], *args: Any) -> bool:
        """A protection setting the instrument has (its capabilities say so) but may refuse: a value outside its
        range (InputError) or an operation it lacks after all (NotSupported) is noted, not fatal; the runner's own
        checks stand in for it."""
        try:
            self.call(what, fn, *args)
            return True
        except InputError as exc:
            self.note_unavailable(what, str(exc))
            return False
        except Abort as exc:
            if exc.kind != "unsupported":
                raise
            self.note_unavailable(what, str(exc.__cause__))
            return False

    def note_unavailable(self, what: str, why: str) -> None:
        """Note that the instrument does not provide ``what`` (the runner checks it itself)."""
        self.stats.notes.append(f"{what}: not available ({why}); runner-side checks only")
        log.warning("%s: not available: %s", what, why)


def instrument_of(fn: Callable[..., Any]) -> Instrument | None:
    """The instrument whose bound method ``fn`` is (None for any other callable)."""
    owner = fn.__self__ if inspect.ismethod(fn) else None
    return owner if isinstance(owner, Instrument) else None


@contextlib.contextmanager
def link_timeout_at_most(device: Instrument | None, timeout_s: float) -> Iterator[None]:
    """The link timeout of ``device`` (where its capabilities say it can be changed) at most ``timeout_s`` for the
    duration."""
    old = device.link_timeout_s if device is not None and device.capabilities.link_timeout else None
    if device is None or old is None or old <= timeout_s:
        yield
        return
    device.link_timeout_s = timeout_s
    try:
        yield
    finally:
        device.link_timeout_s = old


def resync(device: Instrument | None) -> None:
    """After the driver gave up on an exchange, drop a late reply still on its way (reconnect the link) so that
    the retry does not read it as its own."""
    if device is None:
        return
    try:
        device.resync()
    except (InstrumentError, OSError) as exc:
        log.info("link resync failed: %s", exc)
