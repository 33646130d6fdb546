"""The virtual tester's clock: virtual seconds run at ``speed`` × real time, by themselves.

The clock is a pure function of ``time.monotonic`` (it cannot be frozen by a dead host); the lab's ticker
thread advances the simulated instruments along it (:mod:`drivers.virtual.lab`).
"""

from __future__ import annotations

import time


class VirtualClock:
    """``now() = t0 + speed × (monotonic − m0)``; implements :class:`drivers.clock.Clock`."""

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
