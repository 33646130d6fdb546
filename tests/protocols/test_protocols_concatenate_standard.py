"""Concatenation of selected profiles and the standard protocols."""

from __future__ import annotations

import pytest

from protocols import (
    CCCV,
    ConstantCurrent,
    InputError,
    Library,
    ProfileStep,
    Rest,
    SocMethod,
    concatenate,
    conventional,
    hppc,
    ocv_test,
)
from protocols.concatenate import ocv_at
from protocols.constants import TABLE5_OCV

TABLE10_GROUP1 = (
    339,
    342,
    345,
    348,
    365,
)  # ids as in the paper's Table 10 (our grid differs: compare params)


def test_cccv_to_ocv_sets_each_start_soc(lib: Library) -> None:
    profiles = [lib[i] for i in TABLE10_GROUP1]
    c = concatenate(profiles, start_soc=0.5, rest_before_s=900, rest_after_s=300)
    steps = c.protocol.steps
    prof_idx = [k for k, s in enumerate(steps) if isinstance(s, ProfileStep)]
    assert [steps[k].profile.id for k in prof_idx] == list(TABLE10_GROUP1)  # type: ignore[union-attr]
    for k, p in zip(prof_idx, profiles, strict=True):
        assert isinstance(steps[k - 1], Rest) and steps[k - 1].ends[0].value == 900
        assert isinstance(steps[k + 1], Rest) and steps[k + 1].ends[0].value == 300
        before = steps[k - 2]
        if isinstance(before, CCCV):
            assert before.voltage == pytest.approx(ocv_at(p.soc0, TABLE5_OCV))
    r = c.report
    assert r.n_profiles == 5
    assert r.profile_s == pytest.approx(sum(p.duration for p in profiles))
    assert r.rest_s == pytest.approx(5 * 1200)
    assert r.soc_at_profile_start == tuple(p.soc0 for p in profiles)
    assert r.charge_throughput_ah >= 5.0  # five profiles of 1 Ah each, plus the SOC adjustments
    assert r.duration_max_s > r.duration_s > r.profile_s + r.rest_s
    assert c.protocol.limits.current_max == 13.5


def test_unknown_start_soc_resets_first_then_tracks(lib: Library) -> None:
    c = concatenate([lib[725], lib[339]], start_soc=None)  # drive from 0.8, then a charge pulse train from 0.4
    first = c.protocol.steps[0]
    assert isinstance(first, CCCV) and first.voltage == 4.2 and first.current > 0
    to_start = c.protocol.steps[2]
    assert isinstance(to_start, ConstantCurrent) and to_start.current < 0
    assert to_start.ends[0].value == pytest.approx(0.2 * 2.7)  # 1 - 0.8 of the capacity
    soc_after_drive = 0.8 + lib[725].net_charge / 2.7
    assert c.report.soc_end == pytest.approx(0.4 + lib[339].net_charge / 2.7)
    adjust = [s for s in c.protocol.steps if isinstance(s, CCCV)][1]
    assert adjust.current < 0 if soc_after_drive > 0.4 else adjust.current > 0


def test_reset_and_rest_methods(lib: Library) -> None:
    reset = concatenate([lib[1], lib[2]], start_soc=0.3, method=SocMethod.RESET)
    assert sum(isinstance(s, CCCV) and s.voltage == 4.2 for s in reset.protocol.steps) == 2
    rest = concatenate([lib[1], lib[2]], start_soc=0.8, method=SocMethod.REST)
    assert not any(isinstance(s, CCCV | ConstantCurrent) for s in rest.protocol.steps)
    assert rest.report.soc_at_profile_start[1] == pytest.approx(0.8 - 1 / 2.7)  # drift is reported


def test_concatenate_refuses_bad_input(lib: Library) -> None:
    with pytest.raises(InputError, match="no profiles"):
        concatenate([])
    with pytest.raises(InputError, match="no start SOC"):
        concatenate([lib[1].with_meta(soc0=None)], start_soc=0.5)
    with pytest.raises(InputError, match="outside the OCV table"):
        ocv_at(0.9, TABLE5_OCV)


def test_ocv_tests() -> None:
    c20 = ocv_test()
    assert [type(s).__name__ for s in c20.steps] == [
        "CCCV",
        "Rest",
        "ConstantCurrent",
        "Rest",
        "ConstantCurrent",
        "Rest",
    ]
    assert c20.steps[2].current == pytest.approx(-2.7 / 20)  # type: ignore[union-attr]
    c50 = ocv_test(c_rate=1 / 50, cycles=3)
    currents = [s.current for s in c50.steps if isinstance(s, ConstantCurrent)]
    assert currents == pytest.approx([-0.054, 0.054] * 3)
    with pytest.raises(InputError):
        ocv_test(cycles=0)


def test_hppc_and_conventional() -> None:
    h = hppc()
    pulses = [s for s in h.steps if isinstance(s, ConstantCurrent) and s.ends[0].quantity.value == "time"]
    assert len(pulses) == 18 and pulses[0].current == pytest.approx(-2.7) and pulses[1].current == pytest.approx(2.025)
    conv = conventional()
    cc = [s for s in conv.steps if isinstance(s, ConstantCurrent) and "C " in s.label]
    rates = sorted(round(s.current / 2.7, 3) for s in cc)
    assert rates == [
        -2.0,
        -0.333,
        -0.2,
        -0.1,
        0.2,
        0.5,
        1.0,
    ]  # 7 constant-current tests, 0.5C/1C discharge held out
    drive = [s for s in conv.steps if isinstance(s, ProfileStep)]
    assert len(drive) == 1 and drive[0].profile.params["cycle"] == "udds"
