"""Step executors: what current to program when, and when a step ends (rest, cc, cv, cccv, profile).

The engine drives an executor through one protocol per step::

    ex.begin(t0, last)            # t0: the instrument time the step starts; last: the previous sample or None
    loop:  t = ex.next_tick(t)    # the next sample time (on the sample grid, at profile breakpoints, at deadlines)
           i = ex.command(t)      # the current to program from t on (set only when it changes)
           ended = ex.observe(s)  # after measuring: the end condition met, as text, or None

Constant voltage is **regulated by the runner** (the virtual cycler and current-priority supplies do not regulate
voltage in current mode; reaching their voltage limit trips the output off): at every sample the programmed current
moves by ``gain × (V_target − V) / R``, clamped to the step's direction and current bound, with ``R`` the cell's
resistance as seen at the sample period, estimated from the current steps of the run (:class:`ResistanceEstimate`),
and by at most half the step's current bound per sample. The voltage settles within a few samples; between samples
the current is held. A current end condition (the CV taper) counts only while the voltage is held within
``CV_SETTLED_V`` of the target, so a regulation transient does not end the step. A CCCV step's CC phase ends at the
first sample past its voltage.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from battlab.lab.limits import Envelope
from protocols.protocol import (
    CCCV,
    Comparison,
    ConstantCurrent,
    ConstantVoltage,
    EndCondition,
    ProfileStep,
    Quantity,
    Rest,
    Step,
    StepKind,
)

_EPS_T = 1e-6


@dataclass(frozen=True)
class Sample:
    """One measurement: instrument time / s, voltage / V, current / A (positive = charge), surface T / K."""

    t: float
    v: float
    i: float
    T_K: float | None = None


class ResistanceEstimate:
    """The cell's resistance at the sample period: ΔV/ΔI over consecutive samples whose current changed by more
    than ``min_step_A``, averaged exponentially; starts at ``r0_ohm``, kept within [``lo``, ``hi``]."""

    def __init__(self, r0_ohm: float = 0.05, *, min_step_A: float = 0.02, lo: float = 0.002, hi: float = 2.0) -> None:
        self.r_ohm = r0_ohm
        self.min_step_A = min_step_A
        self.lo, self.hi = lo, hi
        self.updates = 0
        self._last: Sample | None = None

    def observe(self, s: Sample) -> None:
        last, self._last = self._last, s
        if last is None:
            return
        di = s.i - last.i
        if abs(di) < self.min_step_A:
            return
        r = (s.v - last.v) / di
        if self.lo <= r <= self.hi:
            w = 0.5 if self.updates < 3 else 0.2
            self.r_ohm = (1 - w) * self.r_ohm + w * r
            self.updates += 1


class StepExecutor:
    """Base: the sample grid, step time, charge moved, and the step's end conditions."""

    def __init__(self, step: Step, period_s: float, ends: tuple[EndCondition, ...]) -> None:
        self.step = step
        self.period_s = period_s
        self.ends = ends
        self.t0 = 0.0
        self.q_Ah = 0.0
        self._prev: Sample | None = None
        self.deadline = min((e.value for e in ends if e.quantity is Quantity.TIME), default=math.inf)

    @property
    def duration_s(self) -> float | None:
        """The planned duration if known (progress display), else None."""
        return self.deadline if math.isfinite(self.deadline) else None

    def begin(self, t0: float, last: Sample | None) -> None:
        self.t0 = t0
        self.q_Ah = 0.0
        self._prev = None

    def rebase(self, t0: float) -> None:
        """The instrument reported when the first setting took effect: the step starts there."""
        self.t0 = t0

    def step_time(self, t: float) -> float:
        return t - self.t0

    def next_tick(self, t: float) -> float:
        """The next sample time after a sample at ``t`` (instrument time)."""
        k = math.floor((t - self.t0) / self.period_s + 1e-9) + 1
        return min(self.t0 + k * self.period_s, self.t0 + self.deadline)

    def command(self, t: float) -> float:
        raise NotImplementedError

    def observe(self, s: Sample) -> str | None:
        prev, self._prev = self._prev, s
        if prev is None:
            self.q_Ah += s.i * max(0.0, s.t - self.t0) / 3600.0
        else:
            self.q_Ah += prev.i * max(0.0, s.t - prev.t) / 3600.0
        return self._check_ends(s, self.active_ends())

    def active_ends(self) -> tuple[EndCondition, ...]:
        """The end conditions that apply now."""
        return self.ends

    def _check_ends(self, s: Sample, ends: tuple[EndCondition, ...]) -> str | None:
        for e in ends:
            q = e.quantity
            if q is Quantity.TIME:
                value = self.step_time(s.t) + _EPS_T
            elif q is Quantity.VOLTAGE:
                value = s.v
            elif q is Quantity.CURRENT:
                value = abs(s.i)
            else:
                value = abs(self.q_Ah) + 1e-12
            if (value >= e.value) if e.op is Comparison.GE else (value <= e.value):
                return str(e)
        return None


class RestExecutor(StepExecutor):
    def __init__(self, step: Rest, period_s: float) -> None:
        super().__init__(step, period_s, step.ends)

    def command(self, t: float) -> float:
        return 0.0


class CCExecutor(StepExecutor):
    def __init__(self, step: ConstantCurrent, period_s: float) -> None:
        super().__init__(step, period_s, step.ends)
        self.current = step.current

    def command(self, t: float) -> float:
        return self.current


#: a CV phase's current end condition counts only while the voltage is held within this band (V)
CV_SETTLED_V = 0.01
#: the regulator moves the current by at most this fraction of its bound per sample
CV_MAX_STEP = 0.5


class CVRegulator:
    """Integral regulation of the current towards a voltage (see the module docstring)."""

    def __init__(self, target_V: float, sign: int, i_max: float, gain: float, resistance: ResistanceEstimate) -> None:
        self.target_V = target_V
        self.sign = sign
        self.i_max = abs(i_max)
        self.gain = gain
        self.resistance = resistance
        self.current = 0.0

    def clamp(self, i: float) -> float:
        return min(max(i, 0.0), self.i_max) if self.sign > 0 else max(min(i, 0.0), -self.i_max)

    def start(self, i0: float) -> None:
        self.current = self.clamp(i0)

    def update(self, v: float) -> float:
        step = self.gain * (self.target_V - v) / self.resistance.r_ohm
        bound = CV_MAX_STEP * self.i_max
        self.current = self.clamp(self.current + min(max(step, -bound), bound))
        return self.current

    def settled(self, v: float) -> bool:
        return abs(v - self.target_V) <= CV_SETTLED_V


class CVExecutor(StepExecutor):
    def __init__(
        self, step: ConstantVoltage, period_s: float, i_max: float, gain: float, resistance: ResistanceEstimate
    ) -> None:
        super().__init__(step, period_s, step.ends)
        self.reg = CVRegulator(step.voltage, step.direction.sign, i_max, gain, resistance)
        self._v: float | None = None

    def begin(self, t0: float, last: Sample | None) -> None:
        super().begin(t0, last)
        v = last.v if last is not None else self.reg.target_V
        self.reg.start(self.reg.gain * (self.reg.target_V - v) / self.reg.resistance.r_ohm)
        self._v = None

    def command(self, t: float) -> float:
        return self.reg.update(self._v) if self._v is not None else self.reg.current

    def active_ends(self) -> tuple[EndCondition, ...]:
        if self._v is not None and self.reg.settled(self._v):
            return self.ends
        return tuple(e for e in self.ends if e.quantity is not Quantity.CURRENT)

    def observe(self, s: Sample) -> str | None:
        self._v = s.v
        return super().observe(s)


class CCCVExecutor(StepExecutor):
    def __init__(self, step: CCCV, period_s: float, gain: float, resistance: ResistanceEstimate) -> None:
        super().__init__(step, period_s, step.ends)
        self.sign = 1 if step.current > 0 else -1
        self.reg = CVRegulator(step.voltage, self.sign, abs(step.current), gain, resistance)
        self.cv = False
        self._v: float | None = None
        self._cc_ends = tuple(e for e in step.ends if e.quantity is not Quantity.CURRENT)

    def begin(self, t0: float, last: Sample | None) -> None:
        super().begin(t0, last)
        self.cv = False
        self._v = None

    def command(self, t: float) -> float:
        if not self.cv:
            return self.step.current  # type: ignore[union-attr]
        return self.reg.update(self._v) if self._v is not None else self.reg.current

    def active_ends(self) -> tuple[EndCondition, ...]:
        return self.ends if self.cv and self._v is not None and self.reg.settled(self._v) else self._cc_ends

    def observe(self, s: Sample) -> str | None:
        if not self.cv and self.sign * (s.v - self.reg.target_V) >= 0:
            self.cv = True
            self.reg.start(self.step.current)  # type: ignore[union-attr]
        self._v = s.v
        return super().observe(s)


class ProfileExecutor(StepExecutor):
    """Zero-order hold of the profile's current; a sample at every breakpoint and on the sample grid."""

    def __init__(self, step: ProfileStep, period_s: float) -> None:
        super().__init__(step, period_s, ())
        p = step.profile
        self.rel = np.asarray(p.t - p.t[0], float)
        self.current = np.asarray(p.current, float)
        self.deadline = float(self.rel[-1])

    def command(self, t: float) -> float:
        k = int(np.searchsorted(self.rel, t - self.t0 + _EPS_T, side="right")) - 1
        return float(self.current[min(max(k, 0), len(self.current) - 2)])

    def next_tick(self, t: float) -> float:
        grid = super().next_tick(t)
        k = int(np.searchsorted(self.rel, t - self.t0 + _EPS_T, side="right"))
        return min(grid, self.t0 + self.rel[k]) if k < len(self.rel) else grid

    def observe(self, s: Sample) -> str | None:
        super().observe(s)
        return "end of profile" if self.step_time(s.t) + _EPS_T >= self.deadline else None


def _cv(step: ConstantVoltage, period_s: float, env: Envelope, gain: float, r: ResistanceEstimate) -> StepExecutor:
    i_max = env.current_charge_max if step.direction.sign > 0 else env.current_discharge_max
    return CVExecutor(step, period_s, i_max, gain, r)


#: The executor of each step kind: (step, sample period [s], envelope, CV gain, resistance estimate) → executor.
EXECUTORS: dict[StepKind, Callable[..., StepExecutor]] = {
    StepKind.REST: lambda step, period, env, gain, r: RestExecutor(step, period),
    StepKind.CC: lambda step, period, env, gain, r: CCExecutor(step, period),
    StepKind.CV: _cv,
    StepKind.CCCV: lambda step, period, env, gain, r: CCCVExecutor(step, period, gain, r),
    StepKind.PROFILE: lambda step, period, env, gain, r: ProfileExecutor(step, period),
}


def executor_for(
    step: Step, period_s: float, envelope: Envelope, *, gain: float, resistance: ResistanceEstimate
) -> StepExecutor:
    """The executor of a protocol step (looked up in :data:`EXECUTORS` by its kind)."""
    make = EXECUTORS.get(step.kind)
    if make is None:
        raise TypeError(f"no executor for step {step!r}")
    return make(step, period_s, envelope, gain, resistance)


__all__ = [
    "EXECUTORS",
    "CCCVExecutor",
    "CCExecutor",
    "CVExecutor",
    "CVRegulator",
    "ProfileExecutor",
    "ResistanceEstimate",
    "RestExecutor",
    "Sample",
    "StepExecutor",
    "executor_for",
]
