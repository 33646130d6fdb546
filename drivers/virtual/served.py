"""What the virtual instruments' servers need of the lab they serve (so they do not import the lab, which
creates them): its lock, its simulated instruments and clock, and ``exchange()`` to bring them to "now" when a
message arrives."""

from __future__ import annotations

import threading
from typing import Protocol

from drivers.virtual.clock import LockStepClock, VirtualClock
from drivers.virtual.instruments import SimulatedChamber, SimulatedCycler


class ServedLab(Protocol):
    lock: threading.RLock
    clock: VirtualClock | LockStepClock
    cycler: SimulatedCycler
    chamber: SimulatedChamber

    def advance(self) -> float:
        """Advance every simulated instrument to the clock's now; returns now [virtual s]."""
        ...

    def exchange(self) -> float:
        """A message arrived: advance (on a lock-step clock, by the exchange's time first); returns now [virtual s]."""
        ...
