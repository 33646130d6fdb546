"""Activation energies from per-temperature refits (battlab.identify.arrhenius)."""

from __future__ import annotations

import numpy as np
import pytest

import battlab
from battlab.identify import fit as F
from battlab.identify.arrhenius import fit_arrhenius, split_by_ambient
from battlab.identify.experiments import Experiment
from battlab.identify.forward import ForwardModel
from protocols.errors import InputError
from protocols.profile import Profile


def _experiment(cell: battlab.Cell, ambient: float) -> Experiment:
    """1C discharge pulses with rests (20 min, 1 s) from SOC 0.8, simulated isothermally enough (0.5C mean)."""
    t = np.arange(0.0, 1200.0, 1.0)
    i = np.where((t % 200.0) < 60.0, -2.7, 0.0)
    prof = Profile(t, i, id=f"pulses{ambient:.0f}")
    res = battlab.simulate(cell, prof, soc0=0.8, ambient=ambient)
    return Experiment(prof.id, prof, res.voltage, 0.8, 1e-6, ambient, None)


def test_an_activation_energy_is_recovered_from_a_refit_at_another_temperature() -> None:
    cell = battlab.Cell.load("nca18650")
    truth = cell.with_values(E_kappa=float(cell["E_kappa"]) + 20e3, E_D_s_n=float(cell["E_D_s_n"]) - 15e3)
    exps = [_experiment(truth, 298.15), _experiment(truth, 273.15), _experiment(truth, 283.15)]
    ref, groups = split_by_ambient(exps, 298.15)
    assert [e.name for e in ref] == ["pulses298"] and sorted(groups) == [273.1, 283.1]
    fm = ForwardModel(cell, v_margin=0.15)
    arr = fit_arrhenius(cell, groups, ["kappa_scale", "D_s_n", "R_f_n"], forward=fm, options=F.Options(max_nfev=12))
    assert arr.names == ("kappa_scale", "D_s_n")  # R_f_n has no activation energy
    # the cell's reference values are those of the truth (only the activation energies differ)
    assert arr.energies["E_kappa"] == pytest.approx(float(truth["E_kappa"]), rel=0.08)
    assert arr.energies["E_D_s_n"] == pytest.approx(float(truth["E_D_s_n"]), rel=0.15)
    assert arr.cell["E_kappa"] == arr.energies["E_kappa"] and arr.cell["kappa_scale"] == cell["kappa_scale"]
    assert all(arr.rmse_after_mV[k] < arr.rmse_before_mV[k] for k in arr.rmse_before_mV)


def test_arrhenius_without_activated_parameters_or_other_temperatures_is_one_clear_error() -> None:
    cell = battlab.Cell.load("nca18650")
    fm = ForwardModel(cell, v_margin=0.15)
    with pytest.raises(InputError, match="none of the fitted parameters has an activation energy"):
        fit_arrhenius(cell, {273.1: []}, ["R_f_n"], forward=fm, options=F.Options())
    with pytest.raises(InputError, match="other than T_ref"):
        fit_arrhenius(cell, {}, ["kappa_scale"], forward=fm, options=F.Options())


def test_a_refit_is_not_held_to_the_reference_range() -> None:
    """A per-temperature value is the reference value that the present activation energy carries to that ambient:
    with κ_scale near its lower bound (0.5) and a true E_κ 25 kJ/mol above the start's, the 0 °C refit needs κ_scale
    0.22, below the bound, and the activation energy is recovered instead of stopping there."""
    cell = battlab.Cell.load("nca18650").with_values(kappa_scale=0.55)
    truth = cell.with_values(E_kappa=float(cell["E_kappa"]) + 25e3)
    _, groups = split_by_ambient([_experiment(truth, 273.15)], 298.15)
    fm = ForwardModel(cell, v_margin=0.15)
    arr = fit_arrhenius(cell, groups, ["kappa_scale"], forward=fm, options=F.Options(max_nfev=12))
    assert next(iter(arr.values.values()))["kappa_scale"] < 0.5
    assert arr.energies["E_kappa"] == pytest.approx(float(truth["E_kappa"]), rel=0.05)


def test_a_cold_refit_starts_where_the_nearer_ambient_carries_the_values() -> None:
    """With activation energies 40 kJ/mol too high, the start cell stops at 38 s of the -15 °C pulses (the voltage
    held after the stop: 1.37 V RMSE, no gradient from the samples it does not reach); refitted from there the energies
    came out 58 and 69 kJ/mol against the truth's 35 and 37. The 10 °C refit goes first and carries the values to
    -15 °C, where the cell runs, and both energies are recovered."""
    truth = battlab.Cell.load("nca18650")
    dE = 40e3
    cell = truth.with_values(E_kappa=float(truth["E_kappa"]) + dE, E_D_e=float(truth["E_D_e"]) + dE)
    _, groups = split_by_ambient([_experiment(truth, 258.15), _experiment(truth, 283.15)], 298.15)
    fm = ForwardModel(cell, v_margin=0.15)
    assert battlab.simulate(cell, groups[258.1][0].profile, soc0=0.8, ambient=258.15).ended_by  # stops early
    arr = fit_arrhenius(cell, groups, ["kappa_scale", "D_e_scale"], forward=fm, options=F.Options(max_nfev=12))
    assert arr.rmse_before_mV["pulses258"] < 10.0 and arr.rmse_after_mV["pulses258"] < 5.0
    for key in ("E_kappa", "E_D_e"):
        assert arr.energies[key] == pytest.approx(float(truth[key]), rel=0.1)
    assert list(arr.values) == [258.1, 283.1]  # reported by ambient, whatever the order of the refits
