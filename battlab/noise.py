"""The measurement-variance model (paper eqs. 36–40): predict the voltage noise level q [V] of a profile.

q is regressed on the L2 input intensity Ĩ = √(∫ I² dt) (eq. 37, I in A, t in s) with a line for charge-only
profiles, an exponential for discharge-only ones and their mean for mixed ones (eqs. 38–39); Q = q² I_n
(eq. 40). The paper's coefficients are the default. With I in A and t in s the charge line is negative at low
intensity, so q is floored at the tester's voltage resolution (docs/decisions.md). :meth:`NoiseModel.fit` refits the
coefficients from repeated runs (eq. 36 gives each run's q).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from enum import Enum

import numpy as np

from protocols.errors import InputError
from protocols.profile import Profile


class Direction(Enum):
    """Whether a profile only charges, only discharges, or both."""

    CHARGE = "charge"
    DISCHARGE = "discharge"
    BOTH = "both"


def intensity(profile: Profile) -> float:
    """Ĩ = √(∫ I² dt) [A s^½] (eq. 37), zero-order hold."""
    return float(np.sqrt(np.sum(profile.current[:-1] ** 2 * np.diff(profile.t))))


def direction(profile: Profile) -> Direction:
    """Charge-only, discharge-only or both (positive current = charge)."""
    i = profile.current[:-1]
    pos, neg = bool(np.any(i > 0)), bool(np.any(i < 0))
    if pos and not neg:
        return Direction.CHARGE
    if neg and not pos:
        return Direction.DISCHARGE
    return Direction.BOTH


def repeat_noise(voltages: np.ndarray) -> float:
    """q = √(mean_k Var_trials V_k) [V] from repeated trials, shape (n_trials, n_samples) (eq. 36)."""
    v = np.asarray(voltages, float)
    if v.ndim != 2 or v.shape[0] < 2:
        raise InputError(f"repeated trials: need an array (n_trials ≥ 2, n_samples), got shape {v.shape}")
    return float(np.sqrt(np.mean(np.var(v, axis=0, ddof=1))))


@dataclass(frozen=True)
class NoiseModel:
    """q̂(Ĩ) per eq. 38–39 with a floor [V]; defaults are the paper's coefficients."""

    a_c: float = 6.2382e-5
    b_c: float = -4.0739e-3
    a_d: float = 2.1045e-4
    b_d: float = 1.7020e-2
    floor: float = 1e-4

    def q_charge(self, I_tilde: float) -> float:
        return max(self.a_c * I_tilde + self.b_c, self.floor)

    def q_discharge(self, I_tilde: float) -> float:
        return max(self.a_d * float(np.exp(min(self.b_d * I_tilde, 700.0))), self.floor)

    def q(self, profile: Profile) -> float:
        """Predicted noise level [V] of a profile (eqs. 37–39)."""
        it = intensity(profile)
        d = direction(profile)
        if d is Direction.CHARGE:
            return self.q_charge(it)
        if d is Direction.DISCHARGE:
            return self.q_discharge(it)
        return max(0.5 * (self.q_charge(it) + self.q_discharge(it)), self.floor)

    def variance(self, profile: Profile) -> float:
        """Q_i = q̂² [V²] (eq. 40; the covariance is Q_i times the identity)."""
        return self.q(profile) ** 2

    @classmethod
    def fit(cls, runs: Sequence[tuple[Profile, np.ndarray]], floor: float = 1e-4) -> NoiseModel:
        """Refit eq. 38 from repeated runs: (profile, voltages of shape (n_trials, n_samples)) pairs.

        Charge-only runs fit the line, discharge-only runs the exponential (linear in log q); a direction with
        fewer than two runs keeps the paper's coefficients. Mixed runs are not used for fitting.
        """
        default = cls()
        groups: dict[Direction, list[tuple[float, float]]] = {Direction.CHARGE: [], Direction.DISCHARGE: []}
        for prof, volts in runs:
            d = direction(prof)
            if d in groups:
                groups[d].append((intensity(prof), repeat_noise(volts)))
        a_c, b_c, a_d, b_d = default.a_c, default.b_c, default.a_d, default.b_d
        ch = np.array(groups[Direction.CHARGE])
        if len(ch) >= 2 and np.ptp(ch[:, 0]) > 0:
            a_c, b_c = np.polyfit(ch[:, 0], ch[:, 1], 1)
        dis = np.array(groups[Direction.DISCHARGE])
        if len(dis) >= 2 and np.ptp(dis[:, 0]) > 0:
            b_d, log_a = np.polyfit(dis[:, 0], np.log(np.maximum(dis[:, 1], 1e-12)), 1)
            a_d = float(np.exp(log_a))
        return cls(float(a_c), float(b_c), float(a_d), float(b_d), floor)
