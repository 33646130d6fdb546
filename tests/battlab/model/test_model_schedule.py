"""The step schedule's current lead: a change of the current taking effect before the sample that logs it."""

from __future__ import annotations

import numpy as np
import pytest

import battlab
from battlab.identify.forward import ForwardModel
from battlab.model import solver
from battlab.model.schedule import schedule
from protocols import Profile


def test_a_current_lead_ends_the_interval_before_a_change_with_a_step_at_the_new_current() -> None:
    t = np.arange(6.0)
    current = np.array([0.0, 1.0, 2.0, 2.0, 3.0, 3.0])
    s = schedule(t, current, 3.0, solver.Settings(adaptive=False, dt_first=0.15, current_lead=0.01))
    lead = np.flatnonzero(s.h == 0.01)
    # one lead step before each sample whose current differs from the one before (1, 2 and 4), none before 3 or 5
    np.testing.assert_allclose(s.t_end[lead], [1.0, 2.0, 4.0])
    np.testing.assert_allclose(s.current[lead], [1.0, 2.0, 3.0])
    assert np.all(s.w[lead] == 0.0)  # backward Euler at the change
    np.testing.assert_allclose(s.t_end[lead - 1], [0.99, 1.99, 3.99])
    np.testing.assert_allclose(s.current[lead - 1], [0.0, 1.0, 2.0])
    # the steps after a lead step grow from it (BDF2 at ratio 2), not from a fresh dt_first
    np.testing.assert_allclose(s.h[lead[0] + 1 : lead[0] + 4], [0.02, 0.04, 0.08])
    np.testing.assert_allclose(s.w[lead[0] + 1 : lead[0] + 4], 2.0)
    np.testing.assert_allclose(s.t_end[s.sample_step], t[1:])  # every sample still ends a step
    np.testing.assert_allclose(np.cumsum(s.h), s.t_end)
    plain = schedule(t, current, 3.0, solver.Settings(adaptive=False, dt_first=0.15))
    assert not np.any(plain.h == 0.01) and plain.current[0] == 0.0
    # a logged current's noise (1 mA on a 3 A cell, below LEAD_MIN_C × 1C) is no setting: no lead step for it
    noisy = schedule(
        t, current + np.array([0, 0, 0, 1e-3, 0, 0]), 3.0, solver.Settings(adaptive=False, current_lead=0.01)
    )
    np.testing.assert_allclose(noisy.t_end[np.isclose(noisy.h, 0.01)], [1.0, 2.0, 4.0])


def test_a_lead_longer_than_half_an_interval_is_not_taken_and_other_schedules_refuse_it() -> None:
    t = np.array([0.0, 1.0, 1.015, 2.0])
    s = schedule(t, np.array([0.0, 1.0, 2.0, 2.0]), 3.0, solver.Settings(adaptive=False, current_lead=0.01))
    assert np.count_nonzero(np.isclose(s.h, 0.01)) == 1  # before t = 1, not inside the 15 ms interval
    with pytest.raises(ValueError, match="aligned"):
        schedule(t, np.zeros(4), 3.0, solver.Settings(adaptive=False, across_samples=True, current_lead=0.01))
    with pytest.raises(ValueError, match=">= 0"):
        schedule(t, np.zeros(4), 3.0, solver.Settings(adaptive=False, current_lead=-0.01))


def _sine() -> Profile:
    t = np.arange(0.0, 181.0)
    return Profile(t, -2.7 + 2.7 * np.sin(2 * np.pi * t / 20.0))


def _moved(p: Profile, lead: float) -> tuple[Profile, np.ndarray]:
    """The profile with each change of the current moved ``lead`` earlier (knots inserted), and where its samples
    went."""
    knots = p.t[1:][np.diff(p.current) != 0] - lead
    t = np.sort(np.concatenate([p.t, knots]))
    k = np.clip(np.searchsorted(p.t, t + lead + 1e-9, side="right") - 1, 0, p.t.size - 1)
    return Profile(t, p.current[k]), np.searchsorted(t, p.t)


@pytest.mark.slow
def test_the_lead_is_the_change_moved_earlier_and_its_sensitivities_stay_exact() -> None:
    """Against a 5 ms solution of the profile whose changes are moved 10 ms earlier, the fit's forward model with a
    10 ms lead is within 0.02 mV (measured 0.0046 mV); without the lead it misses by the 10 ms relaxation after every
    change (0.030 mV). Its sensitivities are the derivatives of its own steps (central differences)."""
    cell = battlab.Cell.load("nca18650")
    p = _sine()
    moved, keep = _moved(p, 0.01)
    fine = solver.Settings(adaptive=False, dt_first=0.005, dt_max=0.005)
    ref = battlab.simulate(cell, moved, soc0=0.6, settings=fine).voltage[keep]
    fm = ForwardModel(cell)
    th = fm.theta_of(cell)
    led = fm.run(th, p, 0.6, sample_delay=0.01, sensitivities=["k_n", "D_s_p"])
    plain = fm.run(th, p, 0.6)
    err_led = 1e3 * np.sqrt(np.mean((led.voltage - ref) ** 2))
    err_plain = 1e3 * np.sqrt(np.mean((plain.voltage - ref) ** 2))
    print(f"RMSE from the moved changes: {err_led:.4f} mV with the lead, {err_plain:.4f} mV without")
    assert err_led < 0.02 and 3 * err_led < err_plain
    names = fm.names
    for j, name in enumerate(["k_n", "D_s_p"]):
        d = np.zeros_like(th)
        d[names.index(name)] = 1e-6
        up = fm.run(th + d, p, 0.6, sample_delay=0.01).voltage
        down = fm.run(th - d, p, 0.6, sample_delay=0.01).voltage
        fd = (up - down) / 2e-6
        np.testing.assert_allclose(led.sensitivities[:, j], fd, atol=1e-5 * max(1.0, np.abs(fd).max()))
    casadi = battlab.simulate(
        cell, p, soc0=0.6, backend="casadi", settings=solver.Settings(adaptive=False, current_lead=0.01)
    )
    native = battlab.simulate(
        cell, p, soc0=0.6, backend="native", settings=solver.Settings(adaptive=False, current_lead=0.01)
    )
    np.testing.assert_allclose(casadi.voltage, native.voltage, atol=1e-9)
    with pytest.raises(ValueError, match="aligned"):
        battlab.simulate(cell, p, soc0=0.6, backend="native", settings=solver.Settings(current_lead=0.01))
