"""Clocks: the virtual clock runs by itself; the host's tracked estimate of it; the lock-step clock.

Real time is a fake here (``time.monotonic`` and ``time.sleep`` of the clocks' modules): it moves only when the
test or a clock's sleep moves it, so every assertion is on what the clocks computed and asked for, none on the
wall clock of a busy host."""

from __future__ import annotations

import time

import pytest

import drivers.clock
import drivers.virtual.clock
from drivers.clock import Clock, RealClock, TrackedClock
from drivers.virtual.clock import LockStepClock, VirtualClock


class FakeTime:
    """``monotonic()`` and ``sleep()`` for the clocks under test; ``slept`` records every real sleep asked for."""

    def __init__(self) -> None:
        self.t = 1000.0
        self.slept: list[float] = []

    def monotonic(self) -> float:
        return self.t

    def sleep(self, seconds: float) -> None:
        self.slept.append(seconds)
        self.t += seconds

    def advance(self, seconds: float) -> None:
        self.t += seconds


@pytest.fixture
def fake_time(monkeypatch: pytest.MonkeyPatch) -> FakeTime:
    fake = FakeTime()
    monkeypatch.setattr(drivers.clock, "time", fake)
    monkeypatch.setattr(drivers.virtual.clock, "time", fake)
    return fake


def test_virtual_clock_runs_at_speed_by_itself(fake_time: FakeTime) -> None:
    clock = VirtualClock(speed=1000.0, t0_s=50.0)
    assert clock.now() == 50.0
    fake_time.advance(0.02)  # 20 real ms, nobody sleeping on the clock
    assert clock.now() == pytest.approx(70.0)
    clock.sleep(30.0)  # 30 virtual s = 30 real ms
    assert fake_time.slept == [pytest.approx(0.03)] and clock.now() == pytest.approx(100.0)
    clock.sleep_until(100.0 + 12.0)
    assert fake_time.slept[-1] == pytest.approx(0.012) and clock.now() == pytest.approx(112.0)
    assert clock.real_seconds(3600.0) == 3.6
    with pytest.raises(ValueError):
        VirtualClock(speed=0.0)


def test_virtual_clock_runs_on_real_time() -> None:
    """The one check on the real monotonic clock: time passes by itself (a lower bound, which load cannot break)."""
    clock = VirtualClock(speed=1000.0)
    a = clock.now()
    time.sleep(0.02)
    assert clock.now() - a >= 19.0


def test_clocks_follow_the_protocol() -> None:
    for clock in (RealClock(), VirtualClock(), TrackedClock(VirtualClock().now, 1000.0)):
        assert isinstance(clock, Clock)


def test_tracked_clock_anchors_on_the_fastest_round_trip(fake_time: FakeTime) -> None:
    """Five round trips of 1 ms, the second 10 ms with the reading late in it: the estimate anchors on a 1 ms one
    (uncertainty half a round trip × speed) and tracks the remote clock exactly; anchored on the slow one it would
    be 4 ms × 500 = 2 s ahead."""
    remote = VirtualClock(speed=500.0, t0_s=1000.0)
    trips: list[float] = []

    def reference() -> float:
        before, after = (0.009, 0.001) if len(trips) == 1 else (0.0005, 0.0005)
        trips.append(before + after)
        fake_time.advance(before)
        reading = remote.now()
        fake_time.advance(after)
        return reading

    tracked = TrackedClock(reference, remote.speed, samples=5)
    assert len(trips) == 5 and trips[1] == pytest.approx(0.01)
    assert tracked.uncertainty_s == pytest.approx(0.5 * 0.001 * 500.0)
    for _ in range(3):
        assert tracked.now() == pytest.approx(remote.now(), abs=1e-9)
        fake_time.advance(0.003)
    tracked.sleep(5.0)
    assert fake_time.slept[-1] == pytest.approx(0.01)


def test_lock_step_clock_moves_only_when_slept_on_and_at_most_at_speed(fake_time: FakeTime) -> None:
    computed: list[float] = []
    clock = LockStepClock(speed=1000.0, t0_s=5.0)

    def advance(t: float) -> None:  # the lab computes its instruments to t, then sets the clock
        computed.append(t)
        clock.set(t)

    clock.bind(advance)
    assert isinstance(clock, Clock) and clock.lockstep and not VirtualClock().lockstep
    fake_time.advance(0.02)
    assert clock.now() == 5.0  # no sleep, no time
    clock.restart(5.0)  # pace from here (the 20 ms just spent would be caught up first)
    for _ in range(3):
        clock.sleep(10.0)
    assert computed == [15.0, 25.0, 35.0] and clock.now() == 35.0
    assert fake_time.slept == [pytest.approx(0.01)] * 3  # 10 virtual s at 1000x: never faster than speed
    fake_time.advance(0.004)  # the lab took 4 real ms to compute the next step: that much less to wait
    clock.sleep(10.0)
    assert fake_time.slept[-1] == pytest.approx(0.006)
    fake_time.advance(1.0)  # a stall far beyond MAX_LAG_REAL_S: written off, not caught up in a burst
    clock.sleep(10.0)
    assert len(fake_time.slept) == 4
    clock.sleep(10.0)  # MAX_LAG_REAL_S behind the new pace, 10 ms ahead: caught up by not waiting
    assert len(fake_time.slept) == 4
    clock.sleep(0.0)
    clock.sleep(-1.0)
    assert computed == [15.0, 25.0, 35.0, 45.0, 55.0, 65.0]
    clock.sleep_until(66.5)
    assert clock.now() == 66.5 and clock.real_seconds(3600.0) == 3.6
    with pytest.raises(ValueError):
        LockStepClock(speed=-1.0)
