"""The virtual tester's clocks: virtual seconds run at up to ``speed`` × real time.

Two modes (``VirtualLabConfig.clock``):

- ``free`` (:class:`VirtualClock`): time runs by itself, a pure function of ``time.monotonic`` (it cannot be
  frozen by a dead host); the lab's ticker advances the simulated instruments along it
  (:mod:`drivers.virtual.lab`). Like a real bench: a host or a physics that cannot keep up leaves samples late,
  and a silent host is caught by the instrument watchdog. For watchdog, fault and timing tests.
- ``lockstep`` (:class:`LockStepClock`): time moves only when the host sleeps on the lab's clock, and only as
  fast as the physics is computed (at most ``speed`` × real time). No sample can be late; for campaigns.
"""

from __future__ import annotations

import time
from collections.abc import Callable

#: how far / real s a lock-step clock may fall behind its pace and still catch up (by not waiting): a stall of the
#: host (a log flush, a busy machine) costs no pace; a longer one is written off rather than made up in a burst
MAX_LAG_REAL_S = 0.1


class VirtualClock:
    """``now() = t0 + speed × (monotonic − m0)``; implements :class:`drivers.clock.Clock`."""

    lockstep = False

    def __init__(self, speed: float = 1000.0, t0_s: float = 0.0) -> None:
        if not speed > 0:
            raise ValueError(f"speed must be > 0, got {speed}")
        self.speed = float(speed)
        self._t0 = float(t0_s)
        self._m0 = time.monotonic()

    def restart(self, t0_s: float = 0.0) -> None:
        """Start counting again from ``t0_s`` now (the lab restarts its clock when it starts serving)."""
        self._t0 = float(t0_s)
        self._m0 = time.monotonic()

    def now(self) -> float:
        """Virtual time / s."""
        return self._t0 + (time.monotonic() - self._m0) * self.speed

    def sleep(self, dt_s: float) -> None:
        """Sleep ``dt_s`` virtual seconds."""
        if dt_s > 0:
            time.sleep(dt_s / self.speed)

    def sleep_until(self, t_s: float) -> None:
        self.sleep(t_s - self.now())

    def real_seconds(self, dt_s: float) -> float:
        """Real seconds that ``dt_s`` virtual seconds take."""
        return dt_s / self.speed


class LockStepClock:
    """Virtual time that moves only when the host sleeps on it or the lab sets it; implements
    :class:`drivers.clock.Clock`.

    ``sleep(dt)`` first has the lab compute its instruments up to ``now + dt`` (in the sleeping thread, under the
    lab's lock; the lab then sets the clock there), then waits out what is left of ``dt / speed`` real seconds.
    Between two sleeps only the lab moves the time (by a fixed virtual time per message it serves), never the real
    time the host or the physics take: a sample is never late. A host or a physics slower than ``speed`` makes the
    clock slower (it catches up at most ``MAX_LAG_REAL_S`` of real time). Time does not move while the host is
    silent: no watchdog trips, and a device fault scheduled at a virtual time fires when the clock crosses it.
    """

    lockstep = True

    def __init__(self, speed: float = 1000.0, t0_s: float = 0.0) -> None:
        if not speed > 0:
            raise ValueError(f"speed must be > 0, got {speed}")
        self.speed = float(speed)
        self._t = float(t0_s)
        self._advance: Callable[[float], None] = self.set
        self.restart(t0_s)

    def bind(self, advance: Callable[[float], None]) -> None:
        """``advance(t)`` brings the instruments to virtual time ``t`` / s and calls :meth:`set` with it."""
        self._advance = advance

    def set(self, t_s: float) -> None:
        """The instruments are at ``t_s`` / s: the clock reads that from now on."""
        self._t = float(t_s)

    def restart(self, t0_s: float = 0.0) -> None:
        """Read ``t0_s`` and pace from this real instant."""
        self._t = float(t0_s)
        self._pace_t, self._pace_m = self._t, time.monotonic()

    def now(self) -> float:
        """Virtual time / s: where the instruments were last computed to."""
        return self._t

    def sleep(self, dt_s: float) -> None:
        """Advance the instruments by ``dt_s`` virtual seconds, taking at least ``dt_s / speed`` real seconds."""
        if not dt_s > 0:
            return
        target = self._t + dt_s
        self._advance(target)
        now_m = time.monotonic()
        wait = self._pace_m + (target - self._pace_t) / self.speed - now_m
        if wait > 0:
            time.sleep(wait)
        elif wait < -MAX_LAG_REAL_S:  # far behind the pace: write the rest off rather than rush on for long
            self._pace_t, self._pace_m = target, now_m - MAX_LAG_REAL_S

    def sleep_until(self, t_s: float) -> None:
        self.sleep(t_s - self.now())

    def real_seconds(self, dt_s: float) -> float:
        """Real seconds that ``dt_s`` virtual seconds take at least."""
        return dt_s / self.speed
