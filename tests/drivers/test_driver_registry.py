"""Drivers found by URL scheme (drivers.registry): the in-tree schemes, messages that list the registered ones, and
a driver registered from outside with one line."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterator

import pytest

from drivers import registry
from drivers.defaults import CyclerDefaults
from drivers.errors import NotSupported
from drivers.factory import open_chamber, open_cycler
from drivers.interfaces import Measurement, ProtectionState
from drivers.registry import CHAMBER, CYCLER, OpenOptions, UrlScheme
from drivers.testing import contract_problems
from drivers.urls import InstrumentURL, parse_url
from protocols.errors import InputError

IN_TREE = {
    CYCLER: {"socket", "serial"},
    CHAMBER: {"modbus-tcp", "modbus-rtu", "modbus-rtu+socket", "espec"},
}


def test_the_in_tree_drivers_register_their_schemes() -> None:
    for role, names in IN_TREE.items():
        assert {s.name for s in registry.schemes_of(role)} == names
        for name in names:
            assert registry.driver_for(role, name) is not None


def test_an_unknown_scheme_lists_the_registered_ones() -> None:
    with pytest.raises(InputError) as info:
        parse_url("arbin://127.0.0.1:9031")
    message = str(info.value)
    assert "unknown scheme 'arbin'" in message and "\n" not in message
    for scheme in registry.url_schemes():
        assert scheme.example in message
    assert message.endswith("or 'virtual'")


def test_a_url_for_the_other_role_names_the_role_and_its_schemes() -> None:
    with pytest.raises(InputError) as info:
        open_chamber("socket://127.0.0.1:5025")
    message = str(info.value)
    assert "no chamber driver for scheme 'socket'" in message
    assert "modbus-tcp://HOST[:PORT]" in message and "espec://HOST[:PORT]" in message
    assert ", socket://" not in message and "a serial device path" not in message
    with pytest.raises(InputError, match="no cycler driver for scheme 'espec'; cycler URLs: socket://HOST:PORT"):
        open_cycler("espec://127.0.0.1")


class LoopCycler(CyclerDefaults):
    """A non-SCPI cycler for the registry tests: a resistor on a current source, in memory."""

    def __init__(self, url: InstrumentURL, options: OpenOptions) -> None:
        self.name = f"cycler[{url.raw}]"
        self.url, self.options, self.i = url, options, 0.0

    def identify(self) -> str:
        return "loop cycler"

    def initialize(self) -> None:
        self.i = 0.0

    def set_current(self, current_A: float) -> None:
        self.i = current_A

    def output(self, on: bool) -> None: ...

    def measure(self) -> Measurement:
        return Measurement(3.7 + 0.05 * self.i, self.i)

    def set_voltage_limits(self, low_V: float | None, high_V: float) -> None:
        if low_V is not None:
            raise NotSupported(self.name, "a low-voltage cut-off")

    def set_current_limits(self, charge_A: float, discharge_A: float) -> None: ...

    def protection(self) -> ProtectionState:
        return ProtectionState(False)

    def errors(self) -> list[tuple[int, str]]:
        return []

    def safe_off(self) -> bool:
        return True

    def close(self) -> None: ...


LOOP = UrlScheme("loop-cycler", options=frozenset({"timeout", "channel"}), default_port=7000)


@pytest.fixture
def loop_driver() -> Iterator[registry.Driver]:
    driver = registry.register(CYCLER, LoopCycler, LOOP, opener=LoopCycler)  # the one registration line
    yield driver
    registry.unregister(driver)


def test_a_new_cycler_is_one_registration_away(loop_driver: registry.Driver) -> None:
    cyc = open_cycler("loop-cycler://127.0.0.1?channel=2", timeout_s=0.5, retries=1)
    assert isinstance(cyc, LoopCycler)
    assert (cyc.url.host, cyc.url.port, cyc.url.option("channel")) == ("127.0.0.1", 7000, "2")
    assert (cyc.options.timeout_s, cyc.options.retries) == (0.5, 1)
    assert contract_problems(cyc, CYCLER) == []
    assert loop_driver in registry.drivers(CYCLER)
    with pytest.raises(InputError, match="unknown option"):
        parse_url("loop-cycler://127.0.0.1?baud=9600")


def test_an_unregistered_driver_is_gone(loop_driver: registry.Driver) -> None:
    registry.unregister(loop_driver)
    with pytest.raises(InputError, match="unknown scheme 'loop-cycler'"):
        parse_url("loop-cycler://127.0.0.1")


def test_a_scheme_is_taken_once_per_role_and_keeps_its_syntax(loop_driver: registry.Driver) -> None:
    class Other(LoopCycler):
        pass

    with pytest.raises(ValueError, match="cycler URL scheme 'loop-cycler' is taken by LoopCycler"):
        registry.register(CYCLER, Other, LOOP, opener=Other)
    with pytest.raises(ValueError, match="registered with another syntax"):
        registry.register(CHAMBER, Other, UrlScheme("loop-cycler"), opener=Other)
    assert registry.driver_for(CHAMBER, "loop-cycler") is None


def test_finding_drivers_does_not_import_pymodbus() -> None:
    """Parsing any URL loads every driver module, but pymodbus only when a Modbus link is opened."""
    code = (
        "import sys\nfrom drivers.urls import parse_url\nparse_url('modbus-tcp://127.0.0.1')\n"
        "assert 'drivers.chambers.watlow_f4t' in sys.modules and 'pymodbus' not in sys.modules, 'pymodbus'\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
