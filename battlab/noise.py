"""The measurement-variance model (paper eqs. 36–40): predict the voltage noise level q [V] of a profile.

q is regressed on the L2 input intensity Ĩ = √(∫ I² dt) (eq. 37, I in A, t in s) with a line for charge-only
profiles, an exponential for discharge-only ones and their mean for mixed ones (eqs. 38–39); Q = q² I_n
(eq. 40). The paper's coefficients are the default. With I in A and t in s the charge line is negative at low
intensity, so q is floored at the tester's voltage resolution (docs/decisions.md). :meth:`NoiseModel.fit` refits the
coefficients from repeated runs (eq. 36 gives each run's q). :func:`save` and :func:`load` keep a model in a file
(``noise.toml``, or the campaign's ``noise/noise.json``) so that a tester's noise measured once weights later fits.
"""

from __future__ import annotations

import json
import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, fields
from enum import Enum
from pathlib import Path
from typing import Any

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


#: [A] currents this small are rest when a profile's direction is taken: a logged rest reads the current sensor's
#: noise (the virtual cycler's: 0.2 mA), of both signs
REST_A = 0.01


def direction(profile: Profile, rest: float = REST_A) -> Direction:
    """Charge-only, discharge-only or both (positive current = charge; |I| ≤ ``rest`` [A] counts as rest)."""
    i = profile.current[:-1]
    pos, neg = bool(np.any(i > rest)), bool(np.any(i < -rest))
    if pos and not neg:
        return Direction.CHARGE
    if neg and not pos:
        return Direction.DISCHARGE
    return Direction.BOTH


def repeat_noise(voltages: np.ndarray) -> float:
    """q [V] from repeated trials, shape (n_trials, n_samples) (eq. 36: q² = mean_k Var_trials V_k), taken on the
    sample-to-sample changes of each trial's deviation from the trials' mean: for white noise of variance q² a
    deviation's change has variance 2 q² (n − 1)/n, while trials that start from slightly different states (a
    rest that ends a little off equilibrium, a start SOC a little off) differ by smooth curves that are no
    measurement noise. Taken on the deviations themselves those dominated: 1.2 mV on four trials of a sine
    profile on the virtual tester whose noise is 0.2 mV."""
    v = np.asarray(voltages, float)
    if v.ndim != 2 or v.shape[0] < 2 or v.shape[1] < 3:
        raise InputError(f"repeated trials: need an array (n_trials ≥ 2, n_samples ≥ 3), got shape {v.shape}")
    m = v.shape[0]
    steps = np.diff(v - v.mean(axis=0), axis=1)
    return float(np.sqrt(np.sum(np.mean(steps**2, axis=1)) / (2.0 * (m - 1))))


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

        Charge-only runs fit the line, discharge-only runs the exponential (linear in log q). A direction measured
        by one run (or by runs of one intensity) gets a constant at its measured q; a direction not measured gets
        the constant of all measured runs (mixed runs included, eq. 39 makes them the mean of the two): the
        paper's coefficients belong to another tester (tens of times this one's noise), so any measurement beats
        them. Without any run the paper's coefficients stay.
        """
        groups: dict[Direction, list[tuple[float, float]]] = {d: [] for d in Direction}
        for prof, volts in runs:
            groups[direction(prof)].append((intensity(prof), repeat_noise(volts)))
        measured = [q for rows in groups.values() for _, q in rows]
        if not measured:
            return cls(floor=floor)
        level = float(np.sqrt(np.mean(np.square(measured))))
        ch = np.array(groups[Direction.CHARGE]).reshape(-1, 2)
        if len(ch) >= 2 and np.ptp(ch[:, 0]) > 0:
            a_c, b_c = (float(x) for x in np.polyfit(ch[:, 0], ch[:, 1], 1))
        else:
            a_c, b_c = 0.0, float(np.sqrt(np.mean(ch[:, 1] ** 2))) if len(ch) else level
        dis = np.array(groups[Direction.DISCHARGE]).reshape(-1, 2)
        if len(dis) >= 2 and np.ptp(dis[:, 0]) > 0:
            b_d, log_a = np.polyfit(dis[:, 0], np.log(np.maximum(dis[:, 1], 1e-12)), 1)
            a_d, b_d = float(np.exp(log_a)), float(b_d)
        else:
            a_d, b_d = float(np.sqrt(np.mean(dis[:, 1] ** 2))) if len(dis) else level, 0.0
        return cls(a_c, b_c, a_d, b_d, floor)

    def to_dict(self) -> dict[str, float]:
        return asdict(self)


def save(model: NoiseModel, path: str | Path, **about: Any) -> Path:
    """Write ``model`` as TOML (``[model]`` with the coefficients, plus ``about``: e.g. where it was measured)."""
    import tomli_w

    path = Path(path)
    path.write_text(tomli_w.dumps({"model": model.to_dict(), **_plain(about)}))
    return path


def load(path: str | Path) -> NoiseModel:
    """A noise model from ``noise.toml`` (:func:`save`) or the campaign's ``noise.json``: a ``model`` table with
    a_c, b_c, a_d, b_d [V, A s^½] and optionally floor [V]. Errors name the file and the field."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise InputError(f"{path}: cannot read the noise model ({exc.strerror or exc})") from None
    try:
        data = json.loads(text) if path.suffix.lower() == ".json" else tomllib.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputError(f"{path}: not a noise model file ({exc})") from None
    raw = data.get("model") if isinstance(data, Mapping) else None
    if not isinstance(raw, Mapping):
        raise InputError(f"{path}: expected a 'model' table with a_c, b_c, a_d, b_d (eq. 38)")
    names = [f.name for f in fields(NoiseModel)]
    unknown = [k for k in raw if k not in names]
    missing = [k for k in names[:4] if k not in raw]
    if unknown or missing:
        what = f"unknown {unknown}" if unknown else f"missing {missing}"
        raise InputError(f"{path}: model: {what}; expected {', '.join(names)}")
    for k, v in raw.items():
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise InputError(f"{path}: model.{k} must be a finite number, got {v!r}")
    model = NoiseModel(**{k: float(v) for k, v in raw.items()})
    if model.floor <= 0:
        raise InputError(f"{path}: model.floor must be positive [V], got {model.floor!r}")
    return model


def _plain(x: Any) -> Any:
    if isinstance(x, Mapping):
        return {str(k): _plain(v) for k, v in x.items() if v is not None}
    if isinstance(x, list | tuple):
        return [_plain(v) for v in x]
    if isinstance(x, np.generic):
        return x.item()
    return x
