"""The fault matrix at driver level, over real loopback sockets.

Every link fault (dropped request, lost reply, garbled reply, delayed reply, disconnect) on every protocol
(SCPI over TCP, Modbus TCP, Modbus RTU over a socket, Espec text): one fault is absorbed by a retry;
``retries + 1`` consecutive faults raise a clean :class:`CommunicationError` in bounded time, after which
the link works again. Device-side safety: a host that cannot talk any more is caught by the instrument
watchdog within 1 s of virtual time, and ``safe_off`` never raises.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import pytest

from drivers.chambers.espec import EspecP300
from drivers.chambers.watlow_f4t import WatlowF4T
from drivers.errors import CommunicationError
from drivers.scpi.cycler import ScpiCycler
from drivers.testing import wait_until
from drivers.virtual.faults import Fault, FaultConfig, FaultInjector
from drivers.virtual.lab import VirtualLab

TIMEOUT = 0.25
RETRIES = 2
LINK_FAULTS = [Fault.DROP, Fault.LOSE_REPLY, Fault.GARBLE, Fault.DELAY, Fault.DISCONNECT]


def _scpi(lab: VirtualLab) -> tuple[Any, Callable[[], object], FaultInjector]:
    cyc = ScpiCycler.open(f"{lab.cycler_url}?timeout={TIMEOUT}", retries=RETRIES)
    cyc.set_current(0.5)

    def op() -> object:
        cyc.set_current(0.5)
        return cyc.measure().voltage_V

    return cyc, op, lab.scpi_faults


def _f4t(url_attr: str) -> Callable[[VirtualLab], tuple[Any, Callable[[], object], FaultInjector]]:
    def make(lab: VirtualLab) -> tuple[Any, Callable[[], object], FaultInjector]:
        ch = WatlowF4T.open(f"{getattr(lab, url_attr)}&timeout={TIMEOUT}", retries=RETRIES)
        ch.read()  # reads the display units once
        return ch, ch.read, lab.modbus_faults

    return make


def _espec(lab: VirtualLab) -> tuple[Any, Callable[[], object], FaultInjector]:
    ch = EspecP300.open(f"{lab.espec_url}?timeout={TIMEOUT}", retries=RETRIES)
    return ch, ch.read, lab.espec_faults


PROTOCOLS = {
    "scpi-tcp": _scpi,
    "modbus-tcp": _f4t("chamber_url"),
    "modbus-rtu-socket": _f4t("rtu_url"),
    "espec-text": _espec,
}


@pytest.fixture
def faulty_lab(make_lab: Callable[..., VirtualLab]) -> VirtualLab:
    delayed = FaultConfig(delay_s=2 * TIMEOUT)
    return make_lab(scpi_faults=delayed, modbus_faults=delayed, espec_faults=delayed)


@pytest.mark.parametrize("fault", LINK_FAULTS, ids=lambda f: f.value)
@pytest.mark.parametrize("protocol", sorted(PROTOCOLS))
def test_one_fault_is_absorbed_by_a_retry(faulty_lab: VirtualLab, protocol: str, fault: Fault) -> None:
    device, op, injector = PROTOCOLS[protocol](faulty_lab)
    baseline = op()
    injector.schedule(fault, 1)
    assert type(op()) is type(baseline)
    assert injector.injected[fault] == 1
    device.close()


@pytest.mark.slow
@pytest.mark.parametrize("fault", LINK_FAULTS, ids=lambda f: f.value)
@pytest.mark.parametrize("protocol", sorted(PROTOCOLS))
def test_persistent_faults_raise_cleanly_then_the_link_recovers(
    faulty_lab: VirtualLab, protocol: str, fault: Fault
) -> None:
    device, op, injector = PROTOCOLS[protocol](faulty_lab)
    injector.schedule(fault, RETRIES + 1)
    t0 = time.monotonic()
    with pytest.raises(CommunicationError, match=f"failed after {RETRIES + 1} attempts"):
        op()
    assert time.monotonic() - t0 < 6.0
    if fault is Fault.DELAY and protocol.startswith("modbus"):
        # The simulated F4T is busy (its single comm task stalls) while it delays a reply, so a retry may
        # overtake a scheduled fault.
        assert 1 <= injector.injected[fault] <= RETRIES + 1
    else:
        assert injector.injected[fault] == RETRIES + 1
    op()  # the next exchange works again
    device.close()


def test_a_short_delay_needs_no_retry(make_lab: Callable[..., VirtualLab]) -> None:
    lab = make_lab(scpi_faults=FaultConfig(delay_s=TIMEOUT / 5))
    cyc = ScpiCycler.open(f"{lab.cycler_url}?timeout={TIMEOUT}", retries=0)
    lab.scpi_faults.schedule(Fault.DELAY, 3)
    for _ in range(3):
        cyc.measure()
    assert lab.scpi_faults.injected[Fault.DELAY] == 3  # every reply was held back, and none needed a retry
    cyc.close()


def test_random_faults_at_ten_percent(make_lab: Callable[..., VirtualLab]) -> None:
    lab = make_lab(scpi_faults=FaultConfig(drop=0.025, lose_reply=0.025, garble=0.025, disconnect=0.025, seed=3))
    cyc = ScpiCycler.open(f"{lab.cycler_url}?timeout={TIMEOUT}", retries=4)
    cyc.set_current(1.0)
    cyc.output(True)
    for _ in range(60):
        assert cyc.measure().current_A == pytest.approx(1.0, abs=0.01)
    assert sum(lab.scpi_faults.injected.values()) > 0
    cyc.safe_off()
    assert not lab.cycler.output_on
    cyc.close()


def test_a_silenced_link_is_caught_by_the_instrument_watchdog(make_lab: Callable[..., VirtualLab]) -> None:
    lab = make_lab(speed=1000.0)
    cyc = ScpiCycler.open(f"{lab.cycler_url}?timeout={TIMEOUT}", retries=1)
    cyc.set_watchdog(5)
    cyc.set_current(1.0)
    cyc.output(True)
    lab.scpi_faults.schedule(Fault.DROP, 10_000)  # nothing reaches the instrument any more
    with pytest.raises(CommunicationError):
        cyc.measure()
    assert cyc.safe_off() is False  # never raises; reports that it could not confirm
    assert wait_until(lambda: not lab.snapshot()["output_on"], 2.0)
    trip = lab.cycler.trips[-1]
    assert "watchdog" in trip.reason and trip.t_s - (lab.cycler.last_io_t + 5) <= 1.0
    cyc.close()


def test_safe_off_survives_one_fault(make_lab: Callable[..., VirtualLab]) -> None:
    lab = make_lab()
    cyc = ScpiCycler.open(f"{lab.cycler_url}?timeout={TIMEOUT}", retries=2)
    cyc.set_current(1.0)
    cyc.output(True)
    lab.scpi_faults.schedule(Fault.GARBLE, 1)
    assert cyc.safe_off() is True and not lab.cycler.output_on
    cyc.close()


def test_safe_off_is_bounded_when_the_instrument_is_gone(make_lab: Callable[..., VirtualLab]) -> None:
    lab = make_lab()
    cyc = ScpiCycler.open(f"{lab.cycler_url}?timeout={TIMEOUT}", retries=1)
    lab.stop()
    t0 = time.monotonic()
    assert cyc.safe_off() is False
    assert time.monotonic() - t0 < 5.0
    cyc.close()
