"""Virtual experiments with a known truth: the model's voltage plus measurement noise, seeded.

Noise per profile: white Gaussian with the noise model's standard deviation q̂ (eqs. 37–39, floored at the
tester's resolution) and quantisation to ``quantum`` (100 µV). The weights of the fit use Q = q̂² + Δ²/12,
which is the variance of that noise (:func:`battlab.identify.experiments.variance_of`).

(The physical virtual tester in ``drivers`` generates its noise from physics and the eq. 38 regression is fitted
to it; here the noise level is set by the noise model on purpose, so that the weights are right and the
interval coverage can be checked against its nominal 95 %.)
"""

from __future__ import annotations

import numpy as np

from battlab.cell import Cell
from battlab.identify.experiments import QUANTUM, Experiment, variance_of
from battlab.identify.forward import ForwardModel
from battlab.noise import NoiseModel
from protocols.errors import InputError
from protocols.profile import Profile


def noise_free(
    forward: ForwardModel, truth: Cell, profile: Profile, soc0: float, *, ambient: float = 298.15
) -> np.ndarray:
    """The true voltage [V] of ``truth`` under ``profile``; a run that stops early is an error."""
    out = forward.run(forward.theta_of(truth), profile, soc0, ambient=ambient)
    if out.ended_by is not None:
        raise InputError(f"virtual experiment {profile.id}: the true cell stops early ({out.ended_by})")
    return out.voltage


def synthesize(
    forward: ForwardModel,
    truth: Cell,
    profile: Profile,
    soc0: float,
    *,
    seed: int,
    noise: NoiseModel | None = None,
    quantum: float = QUANTUM,
    ambient: float = 298.15,
    name: str | None = None,
    clean: np.ndarray | None = None,
) -> Experiment:
    """A virtual experiment: truth + white noise (std q̂ of the profile) quantised to ``quantum``.

    ``clean`` reuses an already simulated noise-free voltage (seeds differ only in the noise).
    """
    noise = noise or NoiseModel()
    v = noise_free(forward, truth, profile, soc0, ambient=ambient) if clean is None else clean
    rng = np.random.default_rng(seed)
    y = v + rng.normal(0.0, noise.q(profile), v.size)
    if quantum > 0:
        y = np.round(y / quantum) * quantum
    return Experiment(
        name or f"profile {profile.id}",
        profile,
        y,
        soc0,
        variance_of(profile, noise, quantum),
        ambient,
        truth=v,
    )
