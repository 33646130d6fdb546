"""Physical measurement noise of the virtual cycler.

The noise is generated from its physical causes, never from the paper's eq. 38 regression (that regression
is fitted to repeated virtual runs): white ADC noise, a current-dependent component (ripple and contact
noise that grow with |I|), the error of sampling at a jittered instant (jitter × dV/dt), and quantisation
to the instrument's resolution (100 µV).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def _quantize(x: float, q: float) -> float:
    return round(x / q) * q if q > 0 else x


@dataclass(frozen=True)
class NoiseModel:
    """Standard deviations and resolutions (SI units); zero switches a component off."""

    voltage_white_V: float = 50e-6
    voltage_per_amp_V: float = 20e-6
    sample_jitter_s: float = 2e-3
    voltage_quantum_V: float = 100e-6
    current_white_A: float = 2e-4
    current_quantum_A: float = 1e-5
    temperature_white_K: float = 0.05
    temperature_quantum_K: float = 0.01

    def voltage(
        self,
        v_true: float,
        current_A: float,
        dvdt_V_s: float,
        rng: np.random.Generator,
        max_slew_error_V: float = math.inf,
    ) -> float:
        """A voltage reading / V. ``max_slew_error_V``: the voltage's change over the last interval the slope was
        taken on; a sample taken at a jittered instant reads between the voltages either side of it, so the jitter
        error is clipped to that (right after a current step the slope over a microsecond is the whole jump)."""
        sigma = self.voltage_white_V + self.voltage_per_amp_V * abs(current_A)
        slew = dvdt_V_s * self.sample_jitter_s * rng.standard_normal()
        slew = min(max(slew, -max_slew_error_V), max_slew_error_V)
        v = v_true + sigma * rng.standard_normal() + slew
        return _quantize(v, self.voltage_quantum_V)

    def current(self, i_true: float, rng: np.random.Generator) -> float:
        """A current reading / A."""
        return _quantize(i_true + self.current_white_A * rng.standard_normal(), self.current_quantum_A)

    def temperature(self, T_true_K: float, rng: np.random.Generator) -> float:
        """A surface-temperature reading / K."""
        return _quantize(T_true_K + self.temperature_white_K * rng.standard_normal(), self.temperature_quantum_K)


#: No noise and no quantisation (for tests that compare against the true state).
NOISELESS = NoiseModel(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
