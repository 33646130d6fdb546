"""Equilibrium identification with the full model (battlab.identify.ocv_model)."""

from __future__ import annotations

import numpy as np
import pytest

from battlab import Cell, parameters
from battlab.identify.ocv_model import (
    NUISANCES,
    OFFSET,
    PACKING_MARGIN,
    SlowCycle,
    cell_with_moles,
    electrode_volume,
    fit_equilibrium_model,
    fitted_samples,
    hac_covariance,
    slow_cycle,
)
from protocols.errors import InputError
from protocols.profile import Profile


def test_moles_make_a_cell_that_every_reachable_porosity_keeps_physical() -> None:
    cell = Cell.load("nca18650")
    hn, hp = cell.electrode_moles("n"), cell.electrode_moles("p")
    same = cell_with_moles(cell, hn, hp, 0.1406)
    assert float(same["eps_s_n"]) == pytest.approx(float(cell["eps_s_n"]), rel=1e-12)
    assert float(same["A"]) == float(cell["A"])
    big = cell_with_moles(cell, hn, 1.05 * hp, 0.1406)  # ε_s⁺ 0.70: more than the electrode holds with ε_e⁺ ≤ 0.33
    assert big.electrode_moles("p") == pytest.approx(1.05 * hp, rel=1e-12)
    assert big.electrode_moles("n") == pytest.approx(hn, rel=1e-12)
    assert float(big["A"]) > float(cell["A"])
    upper = parameters.SPECS["eps_e_p"].upper
    assert float(big["eps_s_p"]) + upper == pytest.approx(1.0 - PACKING_MARGIN, abs=1e-12)
    big.with_values(eps_e_p=upper, eps_e_n=parameters.SPECS["eps_e_n"].upper)  # a valid cell at the bounds
    with pytest.raises(InputError, match="must be positive"):
        cell_with_moles(cell, -hn, hp, 0.1406)


def test_robust_covariance_is_the_usual_one_for_white_residuals_and_wider_for_correlated_ones() -> None:
    rng = np.random.default_rng(1)
    n = 20000
    J = np.c_[np.ones(n), np.linspace(-1, 1, n)]
    white = 1e-4 * rng.standard_normal(n)
    usual = np.sum(white**2) / (n - 2) * np.linalg.inv(J.T @ J)
    assert np.diag(hac_covariance(J, white, n - 2)) == pytest.approx(np.diag(usual), rel=0.15)
    rho = 0.8  # AR(1): the variance of a mean grows by (1 + ρ)/(1 − ρ) = 9
    e = np.empty(n)
    e[0] = white[0]
    for k in range(1, n):
        e[k] = rho * e[k - 1] + white[k]
    usual = np.sum(e**2) / (n - 2) * np.linalg.inv(J.T @ J)
    ratio = hac_covariance(J, e, n - 2, lags=60)[0, 0] / usual[0, 0]
    assert 6.5 < ratio < 11.0


def test_the_cycle_follows_a_rest_and_the_fit_leaves_out_the_steep_ends_and_branch_starts() -> None:
    t = np.arange(0.0, 7200.0, 30.0)
    i = np.r_[0.0, np.full(t.size - 1, -0.135)]
    v = np.r_[4.18, 4.17 - 0.5 * (t[1:] / 7200.0) ** 20]  # steep at the end
    with pytest.raises(InputError, match="must follow a rest"):
        slow_cycle(t, -np.abs(i) - 0.1, v, 1)
    cyc = slow_cycle(t, i, v, 1, "synthetic")
    use = fitted_samples(cyc, 0.27)
    assert not use[cyc.t < 600.0].any()  # the branch's first 600 s
    assert use[(cyc.t > 700.0) & (cyc.t < 5000.0)].all()
    assert not use[-5:].any()  # steeper than 4 V per unit SOC


def _c20_cycle(truth: Cell) -> SlowCycle:
    """A C/20 discharge to 2.5 V, 30 min at rest and a charge to 4.2 V (logged current) simulated on ``truth``."""
    from battlab.identify.forward import ForwardModel

    i = 2.7 / 20
    fm = ForwardModel(truth, v_margin=0.3)
    probe = fm.run(truth.theta_bar(), Profile.constant(-i, 22 * 3600.0, 60.0), 1.0, ambient=298.15)
    n_dis = int(np.argmax(probe.voltage < 2.5)) or probe.voltage.size
    current = np.r_[0.0, np.full(n_dis, -i), np.zeros(30), np.full(n_dis, i)]
    t = 60.0 * np.arange(current.size)
    run = fm.run(truth.theta_bar(), Profile(t, current), 1.0, ambient=298.15)
    k = int(np.argmax(run.voltage > 4.2)) or run.voltage.size
    return SlowCycle(t[:k], current[:k], run.voltage[:k], "synthetic")


@pytest.mark.slow
def test_the_full_model_recovers_the_equilibrium_the_branch_mean_misses() -> None:
    """A C/20 discharge and charge simulated on nca18650 with ε_s⁻ 2 % up and ε_s⁺ 1 % down (its own dynamics):
    the pseudo-OCV fit starts ≥ 0.3 % off, the full model ends within 0.01 % and its intervals cover the truth."""
    base = Cell.load("nca18650")
    truth = cell_with_moles(base, 1.02 * base.electrode_moles("n"), 0.99 * base.electrode_moles("p"), 0.1406)
    eq = fit_equilibrium_model(_c20_cycle(truth), base)
    true = {"eps_s_n": float(truth["eps_s_n"]), "eps_s_p": float(truth["eps_s_p"]), "n_Li": 0.1406}
    start = {"eps_s_n": eq.start.eps_s_n, "eps_s_p": eq.start.eps_s_p, "n_Li": eq.start.n_Li}
    assert max(abs(start[k_] / v - 1) for k_, v in true.items()) > 3e-3
    assert eq.converged and eq.rmse_mV < 0.05
    for name, v in true.items():
        assert eq.estimates[name] == pytest.approx(v, rel=1e-4)
    assert eq.estimates["H_n"] == pytest.approx(truth.electrode_moles("n"), rel=1e-4)
    assert electrode_volume(eq.cell, "p") * float(eq.cell["eps_s_p"]) == pytest.approx(eq.H_p, rel=1e-12)
    assert eq.nuisances["D_s_n"] == pytest.approx(float(base["D_s_n"]), rel=0.05)


@pytest.mark.slow
def test_a_current_sensor_offset_is_fitted_with_the_moles_it_would_otherwise_bias() -> None:
    """A 15 mA offset of the logged current (11 % of C/20) on a cell with ε_s⁻ 2 % up: without it in the model the
    moles come out several per cent off and the cycle misfit by millivolts; with the offset fitted beside them
    (``current_sensor.offset`` among the nuisances) the offset within 0.01 mA and the moles within 0.01 %."""
    base = Cell.load("nca18650")
    moles = (1.02 * base.electrode_moles("n"), base.electrode_moles("p"), 0.1406)
    truth = cell_with_moles(base, *moles).with_extension("current_sensor", offset=0.015)
    cyc = _c20_cycle(truth)
    plain = fit_equilibrium_model(cyc, base, max_simulations=8)
    assert plain.rmse_mV > 2.0
    assert abs(plain.estimates["H_n"] / moles[0] - 1) > 0.02
    eq = fit_equilibrium_model(cyc, base.with_extension("current_sensor"), nuisances=(*NUISANCES, OFFSET))
    assert eq.converged and eq.rmse_mV < 0.05
    assert eq.estimates[OFFSET] == pytest.approx(0.015, abs=1e-5)
    assert 0.0 < eq.ci95[OFFSET][1] - eq.ci95[OFFSET][0] < 1e-3  # an interval, and a narrow one: the cycle informs it
    assert eq.cell.value(OFFSET) == pytest.approx(eq.estimates[OFFSET])
    for got, want in zip((eq.H_n, eq.H_p, eq.n_Li), moles, strict=True):
        assert got == pytest.approx(want, rel=1e-4)
    assert "current_sensor.offset" not in eq.nuisances
