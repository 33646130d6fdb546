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
    """Monotonic time in seconds, and sleeping in that time."""

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

    ``reference()`` asks the instrument for its time (one round trip); the estimate is anchored at the
    midpoint of that round trip and extrapolated with ``time.monotonic``; :meth:`sync` re-anchors it.
    """

    def __init__(self, reference: Callable[[], float], speed: float) -> None:
        if not speed > 0:
            raise ValueError(f"speed must be > 0, got {speed}")
        self._reference = reference
        self.speed = float(speed)
        self._lock = threading.Lock()
        self._t_ref = 0.0
        self._t_mono = time.monotonic()
        self.sync()

    def sync(self) -> None:
        """Re-anchor on the instrument's clock."""
        t0 = time.monotonic()
        t_ref = self._reference()
        t1 = time.monotonic()
        with self._lock:
            self._t_ref, self._t_mono = t_ref, 0.5 * (t0 + t1)

    def observe(self, t_ref: float) -> None:
        """Re-anchor on an instrument time stamp just received (e.g. in a measurement)."""
        with self._lock:
            self._t_ref, self._t_mono = t_ref, time.monotonic()

    def now(self) -> float:
        with self._lock:
            return self._t_ref + (time.monotonic() - self._t_mono) * self.speed

    def sleep(self, dt_s: float) -> None:
        if dt_s > 0:
            time.sleep(dt_s / self.speed)

    def sleep_until(self, t_s: float) -> None:
        self.sleep(t_s - self.now())
