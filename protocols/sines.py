"""Sinusoid profiles of the input library (paper Table 7).

Shapes (f the frequency, t in s), sampled every ``dt``; each sample holds the shape's value at the start of
its interval (so a period's samples never repeat back to back and periods stay distinct steps):

* *both*: ``-sin(2 pi f t)`` (zero mean; discharge first);
* *charge*: ``(1 - cos(2 pi f t)) / 2`` (raised cosine, starts and ends at zero);
* *discharge*: ``-(1 - cos(2 pi f t)) / 2``.

The total time must hold a whole number of periods; one period is computed and tiled, so periods are
bit-identical (exporters can then loop over them). As for pulses, the amplitude follows from the L1
normalisation: A = 1 Ah / (T mean|shape|).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from protocols.constants import L1_CHARGE_AH, SAMPLE_DT_S
from protocols.directions import Direction
from protocols.errors import InputError
from protocols.profile import Profile
from protocols.pulses import normalise_l1


@dataclass(frozen=True)
class SineSpec:
    """Generating parameters of a sinusoid profile (frequency in Hz, total time in s)."""

    frequency_hz: float
    total_s: float
    direction: Direction

    def params(self) -> dict[str, Any]:
        """The generating parameters as plain values (stored with the profile)."""
        return {"frequency_hz": self.frequency_hz, "total_s": self.total_s, "direction": self.direction.value}


def _whole(x: float, what: str) -> int:
    n = round(x)
    if n < 1 or abs(x - n) > 1e-9 * max(1.0, abs(x)):
        raise InputError(f"{what} must be a whole number, got {x:g}")
    return n


def sine_profile(spec: SineSpec, *, charge_ah: float = L1_CHARGE_AH, dt: float = SAMPLE_DT_S, **meta: Any) -> Profile:
    """The sinusoid of ``spec`` sampled every ``dt`` [s], L1-normalised to ``charge_ah`` [Ah]."""
    per_period = _whole(1.0 / (spec.frequency_hz * dt), f"samples per period at {spec.frequency_hz:g} Hz")
    periods = _whole(spec.total_s * spec.frequency_hz, f"periods in {spec.total_s:g} s")
    phase = 2.0 * np.pi * np.arange(per_period) / per_period
    both = spec.direction is Direction.BOTH
    one = -np.sin(phase) if both else spec.direction.sign * (1.0 - np.cos(phase)) / 2.0
    shape = np.tile(one, periods)
    t = np.arange(shape.size + 1) * dt
    meta.setdefault("kind", "sine")
    params = {**spec.params(), **dict(meta.pop("params", {}))}
    return normalise_l1(Profile(t, np.concatenate([shape, shape[-1:]]), params=params, **meta), charge_ah)
