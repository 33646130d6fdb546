"""Every registered driver against its interface (drivers.interfaces): members, signatures, and capabilities that
agree with what the optional operations do. Instances sit on replaying links with no pairs, so nothing is sent."""

from __future__ import annotations

from collections.abc import Callable

import pytest

from drivers import registry
from drivers.chambers.espec import EspecP300
from drivers.chambers.watlow_f4t import WatlowF4T
from drivers.clock import RealClock
from drivers.defaults import CyclerDefaults
from drivers.errors import InstrumentError, NotSupported
from drivers.interfaces import CyclerCapabilities, Measurement, ProtectionState
from drivers.scpi.cycler import ScpiCycler
from drivers.scpi.dialects import DIALECTS
from drivers.testing import ReplayAdapter, ReplayRegisters, contract_problems
from protocols.errors import InputError


def _timed_replay() -> ReplayAdapter:
    adapter = ReplayAdapter([])
    adapter.timeout_s = 2.0  # a link whose read timeout can be changed
    return adapter


#: how to build each registered driver on a silent link: a new driver adds its cases here
CASES: dict[type, dict[str, Callable[[], object]]] = {
    ScpiCycler: {
        **{name: (lambda d=d: ScpiCycler(ReplayAdapter([]), d)) for name, d in DIALECTS.items()},
        "timed link": lambda: ScpiCycler(_timed_replay(), DIALECTS["battlab-virtual"]),
    },
    WatlowF4T: {"registers": lambda: WatlowF4T(ReplayRegisters([]))},
    EspecP300: {"text": lambda: EspecP300(ReplayAdapter([])), "timed link": lambda: EspecP300(_timed_replay())},
}
PARAMS = [
    pytest.param(d.role, build, id=f"{d.cls.__name__}-{case}")
    for d in registry.drivers()
    for case, build in CASES.get(d.cls, {}).items()
]


def test_every_registered_driver_has_contract_cases() -> None:
    registered = {d.cls for d in registry.drivers()}
    assert {ScpiCycler, WatlowF4T, EspecP300} <= registered
    missing = sorted(c.__name__ for c in registered - set(CASES))
    assert not missing, f"registered drivers without a contract case here: {missing}"


@pytest.mark.parametrize(("role", "build"), PARAMS)
def test_registered_drivers_satisfy_the_contract(role: str, build: Callable[[], object]) -> None:
    assert contract_problems(build(), role) == []


def test_scpi_capabilities_follow_the_dialect_table() -> None:
    virtual = ScpiCycler(ReplayAdapter([]), DIALECTS["battlab-virtual"]).capabilities
    keysight = ScpiCycler(ReplayAdapter([]), DIALECTS["keysight-n7951a"]).capabilities
    itech = ScpiCycler(ReplayAdapter([]), DIALECTS["itech-it6012c-80-300"]).capabilities
    assert virtual == CyclerCapabilities(
        clock=True,
        timestamps=True,
        low_voltage_cutoff=True,
        temperature_limit=True,
        watchdog=True,
        clear_protection=True,
    )
    assert keysight == CyclerCapabilities(watchdog=True, clear_protection=True)
    assert itech == CyclerCapabilities(clear_protection=True)


class _Incomplete(CyclerDefaults):
    """A cycler that breaks the contract: no measure, a set_current with another parameter name, a watchdog declared
    but not there (the defaults' set_watchdog), and a low limit taken without declaring the cut-off."""

    name = "incomplete"
    capabilities = CyclerCapabilities(watchdog=True)

    def identify(self) -> str:
        return "incomplete"

    def initialize(self) -> None: ...

    def set_current(self, amps: float) -> None: ...

    def output(self, on: bool) -> None: ...

    def set_voltage_limits(self, low_V: float | None, high_V: float) -> None: ...

    def set_current_limits(self, charge_A: float, discharge_A: float) -> None: ...

    def protection(self) -> ProtectionState:
        return ProtectionState(False)

    def errors(self) -> list[tuple[int, str]]:
        return []

    def safe_off(self) -> bool:
        return True

    def close(self) -> None: ...


def test_the_contract_check_names_what_a_driver_lacks() -> None:
    problems = contract_problems(_Incomplete(), "cycler")
    assert "_Incomplete has no measure" in problems
    assert "_Incomplete.set_current: no parameter 'current_A'" in problems


def test_the_contract_check_catches_capabilities_that_disagree_with_the_operations() -> None:
    class Lying(_Incomplete):
        def set_current(self, current_A: float) -> None: ...

        def measure(self) -> Measurement:
            return Measurement(3.7, 0.0)

    assert sorted(contract_problems(Lying(), "cycler")) == [
        "Lying: set_voltage_limits(2.5, 4.2) does not raise NotSupported but capabilities.low_voltage_cutoff is False",
        "Lying: set_watchdog(60.0) raises NotSupported but capabilities.watchdog is True",
    ]


def test_a_cycler_without_a_clock_reports_the_host_clock() -> None:
    cyc = ScpiCycler(ReplayAdapter([]), DIALECTS["keysight-n7951a"])
    assert not cyc.capabilities.clock and isinstance(cyc.clock(), RealClock)


@pytest.mark.parametrize(
    ("dialect", "call", "what"),
    [
        ("keysight-n7951a", lambda c: c.set_temperature_limit(318.15), "an over-temperature trip"),
        ("keysight-n7951a", lambda c: c.set_voltage_limits(2.5, 4.2), "a low-voltage cut-off"),
        ("itech-it6012c-80-300", lambda c: c.set_watchdog(60.0), "an instrument watchdog"),
        ("itech-it6012c-80-300", lambda c: setattr(c, "link_timeout_s", 1.0), "changing the link timeout"),
    ],
)
def test_an_operation_the_instrument_lacks_is_not_supported_before_any_io(
    dialect: str, call: Callable[[ScpiCycler], object], what: str
) -> None:
    replay = ReplayAdapter([])
    cyc = ScpiCycler(replay, DIALECTS[dialect])
    with pytest.raises(NotSupported) as info:
        call(cyc)
    assert info.value.operation == what and info.value.instrument == cyc.name
    assert "\n" not in str(info.value) and str(info.value).startswith(f"{cyc.name}: {what} is not supported")
    replay.assert_all_used()  # nothing was sent


def test_not_supported_is_neither_a_users_mistake_nor_a_fault() -> None:
    """The same request: a value the instrument's watchdog cannot take is the user's mistake; a watchdog the
    instrument does not have is NotSupported, which no handler of mistakes or faults catches by accident."""
    keysight = ScpiCycler(ReplayAdapter([]), DIALECTS["keysight-n7951a"])
    itech = ScpiCycler(ReplayAdapter([]), DIALECTS["itech-it6012c-80-300"])
    with pytest.raises(InputError, match=r"watchdog_delay .*outside the instrument's range \[1, 3600\]"):
        keysight.set_watchdog(7200)
    with pytest.raises(NotSupported) as info:
        itech.set_watchdog(60)
    assert not isinstance(info.value, InputError | InstrumentError)
