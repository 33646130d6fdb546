"""Fault injection for the virtual instruments' servers (configurable per server) and the lab.

Link faults, decided per received message: ``DROP`` (request lost, not executed, no reply),
``LOSE_REPLY`` (executed, reply lost), ``GARBLE`` (reply corrupted detectably), ``DELAY`` (reply held back
``delay_s`` real seconds), ``DISCONNECT`` (connection closed, request not executed). Each happens with a
probability (:class:`FaultConfig`) or on demand for the next ``n`` messages (:meth:`FaultInjector.schedule`).

Device faults (a chamber alarm, a cell over-temperature) are scheduled in virtual time with
:class:`DeviceFaultPlan` or triggered directly on :class:`drivers.virtual.lab.VirtualLab`.
"""

from __future__ import annotations

import enum
import threading
from collections import Counter, deque
from dataclasses import dataclass

import numpy as np


class Fault(enum.Enum):
    NONE = "none"
    DROP = "drop"
    LOSE_REPLY = "lose_reply"
    GARBLE = "garble"
    DELAY = "delay"
    DISCONNECT = "disconnect"


@dataclass(frozen=True)
class FaultConfig:
    """Per-message fault probabilities of one server, and the delay of a delayed reply (real seconds)."""

    drop: float = 0.0
    lose_reply: float = 0.0
    garble: float = 0.0
    delay: float = 0.0
    disconnect: float = 0.0
    delay_s: float = 0.5
    seed: int = 0

    def __post_init__(self) -> None:
        total = self.drop + self.lose_reply + self.garble + self.delay + self.disconnect
        if min(self.drop, self.lose_reply, self.garble, self.delay, self.disconnect) < 0 or total > 1:
            raise ValueError(f"fault probabilities must be >= 0 and sum to <= 1, got {self}")
        if self.delay_s < 0:
            raise ValueError(f"delay_s must be >= 0, got {self.delay_s}")


@dataclass(frozen=True)
class DeviceFaultPlan:
    """Device faults at virtual times / s (None: never)."""

    chamber_alarm_at_s: float | None = None
    chamber_alarm_code: int = 1
    cell_over_temperature_at_s: float | None = None
    over_temperature_K: float = 273.15 + 75.0


class FaultInjector:
    """Decides the fault of each message; thread-safe; counts what it injected."""

    def __init__(self, config: FaultConfig | None = None) -> None:
        self.config = config or FaultConfig()
        self._rng = np.random.default_rng(self.config.seed)
        self._queue: deque[Fault] = deque()
        self._lock = threading.Lock()
        self.injected: Counter[Fault] = Counter()

    def schedule(self, fault: Fault, count: int = 1) -> None:
        """The next ``count`` messages get ``fault`` (before any random faults)."""
        with self._lock:
            self._queue.extend([fault] * count)

    def next_fault(self) -> Fault:
        with self._lock:
            if self._queue:
                fault = self._queue.popleft()
            else:
                c = self.config
                u = self._rng.random()
                fault = Fault.NONE
                for f, p in (
                    (Fault.DROP, c.drop),
                    (Fault.LOSE_REPLY, c.lose_reply),
                    (Fault.GARBLE, c.garble),
                    (Fault.DELAY, c.delay),
                    (Fault.DISCONNECT, c.disconnect),
                ):
                    if u < p:
                        fault = f
                        break
                    u -= p
            if fault is not Fault.NONE:
                self.injected[fault] += 1
            return fault

    def garble_text(self, reply: str) -> str:
        """Corrupt a text reply so that a strict parser notices: the first character and up to two others
        become ``#``."""
        with self._lock:
            chars = list(reply) or ["#"]
            chars[0] = "#"
            for _ in range(int(self._rng.integers(0, 3))):
                chars[int(self._rng.integers(0, len(chars)))] = "#"
            return "".join(chars)

    def garble_bytes(self, frame: bytes, start: int = 0) -> bytes:
        """Corrupt a binary frame: flip one byte at or after ``start``."""
        with self._lock:
            data = bytearray(frame)
            if len(data) > start:
                i = int(self._rng.integers(start, len(data)))
                data[i] ^= 0xA5
            return bytes(data)
