"""Clocks: the virtual clock runs by itself; the host's tracked estimate of it."""

from __future__ import annotations

import time

import pytest

from drivers.clock import Clock, RealClock, TrackedClock
from drivers.virtual.clock import LockStepClock, VirtualClock


def test_virtual_clock_runs_at_speed_by_itself() -> None:
    clock = VirtualClock(speed=1000.0, t0_s=50.0)
    a = clock.now()
    time.sleep(0.02)
    b = clock.now()
    assert 50.0 <= a < 55.0 and 15.0 < b - a < 200.0
    t0 = time.monotonic()
    clock.sleep(30.0)  # 30 virtual s = 30 ms
    assert 0.025 < time.monotonic() - t0 < 0.5
    assert clock.real_seconds(3600.0) == 3.6
    with pytest.raises(ValueError):
        VirtualClock(speed=0.0)


def test_clocks_follow_the_protocol() -> None:
    for clock in (RealClock(), VirtualClock(), TrackedClock(VirtualClock().now, 1000.0)):
        assert isinstance(clock, Clock)


def test_tracked_clock_estimates_a_remote_clock() -> None:
    remote = VirtualClock(speed=500.0, t0_s=1000.0)
    calls: list[int] = []

    def reference() -> float:
        calls.append(1)
        if len(calls) == 2:
            time.sleep(0.01)  # one slow round trip: sync must not anchor on it
        return remote.now()

    tracked = TrackedClock(reference, remote.speed, samples=5)
    assert len(calls) == 5 and tracked.uncertainty_s < 2.5
    for _ in range(5):
        before, estimate, after = remote.now(), tracked.now(), remote.now()
        assert before - 0.5 - tracked.uncertainty_s <= estimate <= after + 0.5 + tracked.uncertainty_s
        time.sleep(0.003)


def test_lock_step_clock_moves_only_when_slept_on_and_at_most_at_speed() -> None:
    computed: list[float] = []
    clock = LockStepClock(speed=1000.0, t0_s=5.0)

    def advance(t: float) -> None:  # the lab computes its instruments to t, then sets the clock
        computed.append(t)
        clock.set(t)

    clock.bind(advance)
    assert isinstance(clock, Clock) and clock.lockstep and not VirtualClock().lockstep
    time.sleep(0.02)
    assert clock.now() == 5.0  # no sleep, no time
    clock.restart(5.0)  # pace from here (the 20 ms just spent would be caught up first)
    w0 = time.monotonic()
    for _ in range(3):
        clock.sleep(10.0)
    assert computed == [15.0, 25.0, 35.0] and clock.now() == 35.0
    assert time.monotonic() - w0 >= 0.03  # 30 virtual s at 1000x: never faster than speed
    clock.sleep(0.0)
    clock.sleep(-1.0)
    assert computed == [15.0, 25.0, 35.0]
    clock.sleep_until(36.5)
    assert clock.now() == 36.5 and clock.real_seconds(3600.0) == 3.6
    with pytest.raises(ValueError):
        LockStepClock(speed=-1.0)
