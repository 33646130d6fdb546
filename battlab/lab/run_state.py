"""The run's state machine, its counters, and the exceptions that end a run.

States (:class:`RunState`)::

    IDLE → PREFLIGHT → RUNNING → COMPLETED
               │          │
               └──────────┴──→ STOPPING → ABORTED | STOPPED
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Any


class RunState(enum.Enum):
    IDLE = "idle"
    PREFLIGHT = "preflight"
    RUNNING = "running"
    STOPPING = "stopping"
    COMPLETED = "completed"
    ABORTED = "aborted"
    STOPPED = "stopped"


TRANSITIONS: dict[RunState, frozenset[RunState]] = {
    RunState.IDLE: frozenset({RunState.PREFLIGHT}),
    RunState.PREFLIGHT: frozenset({RunState.RUNNING, RunState.STOPPING}),
    RunState.RUNNING: frozenset({RunState.STOPPING, RunState.COMPLETED}),
    RunState.STOPPING: frozenset({RunState.ABORTED, RunState.STOPPED}),
    RunState.COMPLETED: frozenset(),
    RunState.ABORTED: frozenset(),
    RunState.STOPPED: frozenset(),
}


class Abort(Exception):
    """Ends the run: ``kind`` (``safety``, ``protection``, ``chamber``, ``communication``, ``instrument``,
    ``preflight``, ``regulation``, ``internal``) and a message naming the cause; ``device``: the instrument whose
    link failed (a communication abort), which the safe shutdown then spares its retries."""

    def __init__(self, kind: str, message: str, *, device: Any = None) -> None:
        super().__init__(f"{kind}: {message}")
        self.kind = kind
        self.message = message
        self.device = device


class StopRequested(Exception):
    """The operator asked to stop (Ctrl-C)."""


@dataclass
class RunStats:
    """Counters for the summary and the benchmark (wall times in s)."""

    samples: int = 0
    current_sets: int = 0
    retries: int = 0
    late_samples: int = 0
    max_late_s: float = 0.0
    sum_late_s: float = 0.0
    #: gaps in sampling longer than 1.5 sample periods (marked in the log), their longest and total / s
    gaps: int = 0
    max_gap_s: float = 0.0
    sum_gap_s: float = 0.0
    #: watches of the instruments while waiting for the next sample (slow clocks only)
    heartbeats: int = 0
    loop_wall_s: float = 0.0
    io_wall_s: float = 0.0
    sleep_wall_s: float = 0.0
    sink_wall_s: float = 0.0
    #: from the instant a new current took effect (instrument's stamp) to the next sample's stamp
    max_set_to_sample_s: float = 0.0
    sum_set_to_sample_s: float = 0.0
    set_to_sample_n: int = 0
    resistance_ohm: float = math.nan
    notes: list[str] = field(default_factory=list)

    @property
    def overhead_per_sample_s(self) -> float:
        """Wall time per sample the runner spends outside instrument calls and sleeps (incl. logging)."""
        return max(0.0, self.loop_wall_s - self.io_wall_s - self.sleep_wall_s) / max(1, self.samples)

    def to_dict(self) -> dict[str, Any]:
        n = max(1, self.samples)
        return {
            "samples": self.samples,
            "current_sets": self.current_sets,
            "retries": self.retries,
            "late_samples": self.late_samples,
            "mean_late_s": self.sum_late_s / n,
            "max_late_s": self.max_late_s,
            "gaps": self.gaps,
            "max_gap_s": self.max_gap_s,
            "sum_gap_s": self.sum_gap_s,
            "heartbeats": self.heartbeats,
            "overhead_per_sample_s": self.overhead_per_sample_s,
            "io_per_sample_s": self.io_wall_s / n,
            "mean_set_to_sample_s": self.sum_set_to_sample_s / max(1, self.set_to_sample_n),
            "max_set_to_sample_s": self.max_set_to_sample_s,
            "resistance_ohm": self.resistance_ohm,
            "notes": list(self.notes),
        }
