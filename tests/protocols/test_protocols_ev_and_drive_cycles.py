"""EV model and drive-cycle profiles."""

from __future__ import annotations

import numpy as np
import pytest

from protocols import Cycle, EVModel, InputError, drive_profile, speed_trace
from protocols.drive_cycles import naturalistic_trips, repeats_for_limit
from protocols.ev_model import GRAVITY_M_S2


def test_cruise_power_is_drag_plus_rolling_and_traction_is_discharge() -> None:
    ev = EVModel(aux_power_w=0.0)
    t = np.arange(11.0)
    v = np.full(11, 20.0)
    p_wheel = ev.wheel_power(t, v)
    by_hand = (0.5 * 1.2 * 0.24 * 2.34 * 20.0**2 + 2100.0 * GRAVITY_M_S2 * 0.009) * 20.0
    assert p_wheel == pytest.approx(np.full(10, by_hand))
    i = ev.cell_current(t, v)
    assert np.all(i < 0)
    assert i[0] == pytest.approx(-by_hand / 0.9 / (96 * 74 * 3.6))


def test_braking_recovers_charge_within_the_regen_limit() -> None:
    ev = EVModel(aux_power_w=0.0, regen_power_limit_w=10e3)
    t = np.arange(3.0)
    v = np.array([30.0, 25.0, 20.0])  # hard braking: far more than 10 kW at the wheels
    i = ev.cell_current(t, v)
    assert np.all(i > 0)
    assert i == pytest.approx(np.full(2, 10e3 / (96 * 74 * 3.6)))
    slow = ev.cell_current(t, np.array([2.0, 1.0, 0.0]))  # below the regen speed: friction brakes only
    assert np.all(slow == 0.0)


def test_auxiliary_load_discharges_at_standstill() -> None:
    i = EVModel(aux_power_w=500.0).cell_current(np.arange(3.0), np.zeros(3))
    assert i == pytest.approx(np.full(2, -500.0 / (96 * 74 * 3.6)))


@pytest.mark.parametrize("field,value", [("mass_kg", 0.0), ("drivetrain_efficiency", 1.5), ("cells_in_series", 0)])
def test_ev_model_rejects_impossible_parameters(field: str, value: float) -> None:
    with pytest.raises(InputError, match=field.split("_")[0]):
        EVModel(**{field: value})


def test_regulatory_traces_have_their_published_durations() -> None:
    durations = {c: speed_trace(c).duration for c in (Cycle.UDDS, Cycle.US06, Cycle.HWFET, Cycle.WLTC3B)}
    assert durations == {Cycle.UDDS: 1369.0, Cycle.US06: 600.0, Cycle.HWFET: 765.0, Cycle.WLTC3B: 1800.0}
    assert speed_trace(Cycle.US06).speed_mps.max() == pytest.approx(35.897312)


def test_naturalistic_trips_are_named_and_long_enough() -> None:
    dc1, dc2 = speed_trace(Cycle.DC1), speed_trace(Cycle.DC2)
    assert "2007-05-24 06:35:12-06:48:47" in dc1.source
    assert "19:12:23-19:19:29 + 2007-05-24 19:59:08-20:03:45" in dc2.source
    assert dc1.duration >= 600 and dc2.duration >= 600
    trips = naturalistic_trips()
    evening = [t for t in trips if t.start.hour >= 18]
    assert all((t.end - t.start).total_seconds() < 600 for t in evening)  # why DC2 joins trips
    assert dc2.speed_mps[0] == 0 and dc2.speed_mps[-1] == 0
    assert np.all(np.diff(dc2.t) == 1.0)


@pytest.mark.parametrize("cycle", list(Cycle))
def test_drive_profile_is_normalised_and_repeated_just_enough(cycle: Cycle) -> None:
    p = drive_profile(cycle, soc0=0.6)
    assert p.charge_throughput == pytest.approx(1.0, abs=1e-12)
    assert p.max_abs_current <= 13.5
    k = p.params["repeats"]
    assert p.duration == pytest.approx(k * speed_trace(cycle).duration)
    if k > 1:
        assert p.max_abs_current * k / (k - 1) > 13.5  # one repeat fewer would break 5C
    assert p.net_charge < 0  # driving discharges on balance
    assert p.kind == "drive" and p.soc0 == 0.6


def test_repeats_rule() -> None:
    assert repeats_for_limit(13.5, 13.5) == 1
    assert repeats_for_limit(13.6, 13.5) == 2
    assert repeats_for_limit(40.6, 13.5) == 4
