"""The plans the compiled stepper reads: the steps of a run (:class:`StepPlan`), its output samples with the
interpolation history kept between calls (:class:`SamplePlan`), and the state of error-controlled stepping with
the steps it accepted (:class:`AdaptiveControl`). Contiguous float64/int32 arrays, as the C code reads them."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class AdaptiveControl:
    """The state of error-controlled stepping kept between ``bl_adapt`` calls, and the steps it accepted (a plan
    that ``bl_run`` replays)."""

    settings: np.ndarray  # rtol, atol, hmax [s], growth, dt_first [s]
    #: t, next h, h1, h2, steps in segment, inside segment 0, called again after a pivot re-analysis
    state: np.ndarray = field(default_factory=lambda: np.zeros(7))
    h: np.ndarray = field(default_factory=lambda: np.zeros(1024))
    w: np.ndarray = field(default_factory=lambda: np.zeros(1024))
    current: np.ndarray = field(default_factory=lambda: np.zeros(1024))
    t_end: np.ndarray = field(default_factory=lambda: np.zeros(1024))
    n: int = 0

    def grow(self) -> None:
        """Twice the room for accepted steps."""
        for name in ("h", "w", "current", "t_end"):
            old = getattr(self, name)
            new = np.zeros(2 * old.size)
            new[: old.size] = old
            setattr(self, name, new)


@dataclass(frozen=True)
class StepPlan:
    """The steps of a ``bl_run`` call: h [s], ω, I_dis [A], T_amb [K], end time [s] and whether samples may be
    written after each (contiguous arrays, as the C code reads them)."""

    h: np.ndarray
    w: np.ndarray
    current: np.ndarray
    T_amb: np.ndarray
    t_end: np.ndarray
    emit: np.ndarray

    @classmethod
    def of(cls, h, w, current, T_amb, t_end, emit) -> StepPlan:  # noqa: ANN001
        d = lambda x: np.ascontiguousarray(x, dtype=np.float64)  # noqa: E731
        return cls(d(h), d(w), d(current), d(T_amb), d(t_end), np.ascontiguousarray(emit, dtype=np.int32))

    def __getitem__(self, sl: slice) -> StepPlan:
        return StepPlan(
            *(np.ascontiguousarray(a[sl]) for a in (self.h, self.w, self.current, self.T_amb, self.t_end, self.emit))
        )


@dataclass
class SamplePlan:
    """The samples of a run: times [s] (on the steps' clock), the current that starts at each [A], the next one to
    write, and, for steps across samples, the interpolation history the C code keeps between calls (the starts of
    the current and the previous step: 2 states and 2 × n × ns sensitivities)."""

    t: np.ndarray
    current: np.ndarray
    next: int = 0
    yhist: np.ndarray | None = None
    Shist: np.ndarray | None = None

    @classmethod
    def of(cls, t, current, n: int = 0, ns: int = 0, dense: bool = False, depth: int = 2) -> SamplePlan:  # noqa: ANN001
        """``depth``: the step starts kept (2 for replayed plans, 3 for error-controlled steps)."""
        d = lambda x: np.ascontiguousarray(x, dtype=np.float64)  # noqa: E731
        return cls(
            d(t), d(current), 0, np.zeros(depth * n) if dense else None, np.zeros(2 * n * ns) if dense and ns else None
        )
