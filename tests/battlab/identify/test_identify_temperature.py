"""The logged surface temperature as a second measured channel of a fit: its noise level read off its own
sample-to-sample changes, its residuals weighted by it beside the voltage's, its exact sensitivities from the
model; with it a heat-transfer change is identified at one ambient temperature."""

from __future__ import annotations

import numpy as np
import pytest

import battlab
from battlab import Cell
from battlab.identify import fit as F
from battlab.identify.experiments import Experiment, temperature_noise_variance
from battlab.identify.forward import ForwardModel
from protocols import Cycle, Profile, drive_profile


def test_the_temperature_noise_is_read_off_its_own_changes() -> None:
    rng = np.random.default_rng(0)
    slow = 298.15 + 3.0 * np.sin(np.linspace(0.0, 3.0, 3000))
    assert np.sqrt(temperature_noise_variance(slow + rng.normal(0.0, 0.05, slow.size))) == pytest.approx(0.05, rel=0.1)
    quantised = np.round(slow / 0.1) * 0.1  # a logger with 0.1 K steps, mostly flat between them
    assert np.sqrt(temperature_noise_variance(quantised)) == pytest.approx(0.1 / np.sqrt(12.0), rel=0.05)


@pytest.mark.slow
def test_a_heat_transfer_change_is_fitted_from_the_logged_temperature_at_one_ambient() -> None:
    start = Cell.load("nca18650").with_extension("thermal")
    truth = start.with_values(**{"thermal.h2a_scale": 2.0})
    udds = drive_profile(Cycle.UDDS)
    t = np.arange(0.0, 2401.0)
    prof = Profile(t, 1.5 * udds.value_at(np.mod(t, float(udds.t[-1]))), id="udds")
    res = battlab.simulate(truth, prof, soc0=0.7)
    assert res.ended_by is None, res.ended_by
    rng = np.random.default_rng(1)
    sigma_v, sigma_T = 1e-3, 0.05
    e = Experiment(
        "udds",
        prof,
        res.voltage + rng.normal(0.0, sigma_v, t.size),
        0.7,
        sigma_v**2,
        temperature=res.T_surface + rng.normal(0.0, sigma_T, t.size),
        t_variance=sigma_T**2,
    )
    fm = ForwardModel(start)
    name = ["thermal.h2a_scale"]
    with_T = F.fit(start, [e], name, forward=fm, options=F.Options(max_nfev=15, temperature=True))
    est = with_T.statistics["thermal.h2a_scale"]
    assert est.ci95[0] <= 2.0 <= est.ci95[1] and abs(est.value - 2.0) < 0.05, est
    voltage_only = F.fit(start, [e], name, forward=fm, options=F.Options(max_nfev=15))
    wide = voltage_only.statistics["thermal.h2a_scale"]
    # the temperature informs it far more than the voltage does (a few kelvin of self-heating)
    assert (wide.ci95[1] - wide.ci95[0]) > 5 * (est.ci95[1] - est.ci95[0])
