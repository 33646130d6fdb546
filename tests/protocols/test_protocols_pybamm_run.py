"""The PyBaMM export runs in PyBaMM and applies the profile with PyBaMM's sign."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from protocols import ConstantCurrent, Direction, ProfileStep, Protocol, PulseSpec, Rest, pulse_profile
from protocols.export import Format, export
from protocols.export.pybamm import RAMP_S, load_module
from tests.conftest import reference


@pytest.mark.slow
def test_exported_module_runs_in_pybamm(tmp_path: Path) -> None:
    pybamm = reference("pybamm")
    profile = pulse_profile(PulseSpec(10.0, 1, 60.0, Direction.BOTH), charge_ah=0.02, id="short", soc0=0.6)
    proto = Protocol(
        "pybamm check",
        (
            Rest(("time >= 10",)),
            ProfileStep(profile),
            ConstantCurrent(-1.0, ("time >= 20", "voltage <= 2.6")),
        ),
    )
    module = load_module(export(proto, Format.PYBAMM, tmp_path).path)
    experiment = module.experiment()
    assert isinstance(experiment, pybamm.Experiment)
    params = pybamm.ParameterValues("Chen2020")
    params.update(module.parameter_updates())
    sim = pybamm.Simulation(pybamm.lithium_ion.SPM(), parameter_values=params, experiment=experiment)
    sol = sim.solve(initial_soc=0.6)
    t_end = sol["Time [s]"].entries[-1]
    assert t_end == pytest.approx(10.0 + 60.0 + 20.0, abs=1e-6)
    current = sol["Current [A]"]
    # inside every hold (away from the 1 ms ramps) PyBaMM's current is minus ours
    t_profile = 10.0 + np.linspace(0.0, profile.duration, 600, endpoint=False) + 0.0503
    ours = profile.value_at(t_profile - 10.0)
    edges = profile.t
    gap = np.min(np.abs((t_profile - 10.0)[:, None] - edges[None, :]), axis=1)
    assert gap.min() > 2 * RAMP_S
    np.testing.assert_allclose(current(t=t_profile), -ours, atol=1e-6)
    np.testing.assert_allclose(current(t=np.array([5.0, 80.0])), [0.0, 1.0], atol=1e-6)  # rest, 1 A discharge
    v = sol["Voltage [V]"].entries
    assert np.all((v > 2.45) & (v < 4.25))
