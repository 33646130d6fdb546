"""Clocks: the one time unit is the second.

A :class:`Clock` is what the runner and :meth:`Chamber.wait_stable` sleep on. The real bench uses
:class:`RealClock`; the virtual tester's accelerated clock (``drivers.virtual.clock.VirtualClock``) and
:class:`TrackedClock` (the host's view of a remote virtual instrument's clock) follow the same protocol.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Protocol, runtime_checkable


@runtime_checkable
class Clock(Protocol):
    """Monotonic time in seconds, and sleeping in that time; ``speed``: its seconds per real second (1 for wall
    time, more for an accelerated virtual clock)."""

    speed: float

    def now(self) -> float:
        """Current time / s."""
        ...

    def sleep(self, dt_s: float) -> None:
        """Sleep ``dt_s`` seconds of this clock's time."""
        ...


class RealClock:
    """Wall time (``time.monotonic``)."""

    speed = 1.0

    def now(self) -> float:
        return time.monotonic()

    def sleep(self, dt_s: float) -> None:
        if dt_s > 0:
            time.sleep(dt_s)

    def sleep_until(self, t_s: float) -> None:
        self.sleep(t_s - self.now())


class TrackedClock:
    """The host's estimate of a remote clock that runs at ``speed`` × real time.

    ``reference()`` asks the instrument for its time (one round trip). :meth:`sync` keeps the round trip
    with the shortest duration out of ``samples`` and anchors the estimate at its midpoint (the error is at
    most half that round trip × speed); the estimate is then extrapolated with ``time.monotonic``. The
    virtual instrument's clock is itself a function of the same monotonic clock, so the estimate does not
    drift; call :meth:`sync` again after a long pause if in doubt.
    """

    def __init__(self, reference: Callable[[], float], speed: float, *, samples: int = 5) -> None:
        if not speed > 0:
            raise ValueError(f"speed must be > 0, got {speed}")
        self._reference = reference
        self.speed = float(speed)
        self.samples = max(1, samples)
        self._lock = threading.Lock()
        self._t_ref = 0.0
        self._t_mono = time.monotonic()
        self.uncertainty_s = float("inf")
        self.sync()

    def sync(self) -> None:
        """Re-anchor on the instrument's clock (best of ``samples`` round trips)."""
        best: tuple[float, float, float] | None = None
        for _ in range(self.samples):
            t0 = time.monotonic()
            t_ref = self._reference()
            t1 = time.monotonic()
            if best is None or t1 - t0 < best[0]:
                best = (t1 - t0, t_ref, 0.5 * (t0 + t1))
        assert best is not None
        with self._lock:
            self.uncertainty_s = 0.5 * best[0] * self.speed
            self._t_ref, self._t_mono = best[1], best[2]

    def now(self) -> float:
        with self._lock:
            return self._t_ref + (time.monotonic() - self._t_mono) * self.speed

    def sleep(self, dt_s: float) -> None:
        if dt_s > 0:
            time.sleep(dt_s / self.speed)

    def sleep_until(self, t_s: float) -> None:
        self.sleep(t_s - self.now())
