"""Pulse-train profiles of the input library (paper Table 6).

A pulse train has pulse width ``w`` [s], rest ``n * w`` after each pulse (the "duty cycle n * (pulse
width)" of Table 6, n in {1, 2, 3}: on-fraction 1/(1+n)), and total duration ``T`` [s]. Pulses start at
``k (1 + n) w`` for k = 0 .. N-1 where N = floor((T - w) / ((1 + n) w)) + 1 is the number of pulses that fit;
the profile rests from the end of the last pulse to ``T``.

Directions: a *discharge* (*charge*) train has every pulse at -A (+A). A *both* train has bipolar pulses:
-A for w/2 then +A for w/2 (charge-neutral, so it is allowed from every start SOC); this is the only place the
library needs samples finer than 1 s (w = 1 s and w = 3 s give 0.5 s half-pulses).

Amplitude: with the L1 normalisation to 1 Ah the amplitude is not a free variable: A = 1 Ah / (N w), so Table
6's amplitude axis (0.5C..5C) is replaced by (w, n, T), which set the on-time N w and hence A.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from protocols.constants import L1_CHARGE_AH, SAMPLE_DT_S
from protocols.directions import Direction
from protocols.errors import InputError
from protocols.profile import Profile
from protocols.sampling import sample_piecewise


@dataclass(frozen=True)
class PulseSpec:
    """Generating parameters of a pulse train (widths and durations in s)."""

    width_s: float
    rest_factor: int
    total_s: float
    direction: Direction

    @property
    def period_s(self) -> float:
        """Pulse period (1 + n) w [s]."""
        return (1 + self.rest_factor) * self.width_s

    @property
    def n_pulses(self) -> int:
        """Number of whole pulses that fit in the total time (0 if not even one)."""
        if self.total_s < self.width_s:
            return 0
        return int((self.total_s - self.width_s) // self.period_s) + 1

    def amplitude_a(self, charge_ah: float = L1_CHARGE_AH) -> float:
        """Pulse amplitude [A] that makes the L1 norm equal ``charge_ah`` [Ah]."""
        n = self.n_pulses
        if n == 0:
            raise InputError(f"pulse width {self.width_s:g} s does not fit in {self.total_s:g} s")
        return charge_ah * 3600.0 / (n * self.width_s)

    def params(self) -> dict[str, Any]:
        """The generating parameters as plain values (stored with the profile)."""
        return {
            "width_s": self.width_s,
            "rest_factor": self.rest_factor,
            "total_s": self.total_s,
            "direction": self.direction.value,
            "n_pulses": self.n_pulses,
        }


def pulse_pieces(spec: PulseSpec) -> tuple[np.ndarray, np.ndarray]:
    """Piecewise-constant shape with unit amplitude: (edges [s] with edges[0] = 0, edges[-1] = T, values)."""
    n = spec.n_pulses
    if n < 1:
        raise InputError(f"pulse width {spec.width_s:g} s does not fit in {spec.total_s:g} s")
    w, p = spec.width_s, spec.period_s
    starts = np.arange(n) * p
    if spec.direction is Direction.BOTH:
        cuts = np.column_stack([starts, starts + w / 2, starts + w]).reshape(-1)
        vals = np.tile([-1.0, 1.0, 0.0], n)
    else:
        cuts = np.column_stack([starts, starts + w]).reshape(-1)
        vals = np.tile([float(spec.direction.sign), 0.0], n)
    edges = np.concatenate([cuts, [spec.total_s]])
    if edges[-1] == edges[-2]:  # the last pulse ends exactly at T: drop the empty trailing rest
        edges, vals = edges[:-1], vals[:-1]
    return edges, vals


def pulse_profile(spec: PulseSpec, *, charge_ah: float = L1_CHARGE_AH, dt: float = SAMPLE_DT_S, **meta: Any) -> Profile:
    """The pulse train of ``spec`` sampled every ``dt`` [s] and at every edge, L1-normalised [Ah]."""
    edges, vals = pulse_pieces(spec)
    t, shape = sample_piecewise(edges, vals, dt)
    meta.setdefault("kind", "pulse")
    params = {**spec.params(), **dict(meta.pop("params", {}))}
    return normalise_l1(Profile(t, shape, params=params, **meta), charge_ah)


def normalise_l1(profile: Profile, charge_ah: float = L1_CHARGE_AH) -> Profile:
    """Scale ``profile`` so that its charge throughput is ``charge_ah`` [Ah]; records the scale [A]."""
    q = profile.charge_throughput
    if q <= 0:
        raise InputError(f"profile {profile.id}: zero current everywhere, cannot L1-normalise")
    scale = charge_ah / q
    params = {**dict(profile.params), "l1_scale": scale}
    return Profile(
        profile.t, profile.current * scale, id=profile.id, kind=profile.kind, soc0=profile.soc0, params=params
    )
