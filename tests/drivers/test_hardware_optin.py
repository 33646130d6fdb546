"""Opt-in tests against real instruments (pymeasure's practice): skipped unless a URL is given.

    BATTLAB_HW_CYCLER=socket://CYCLER-HOST:5025 BATTLAB_HW_DIALECT=keysight-n7951a pytest tests/drivers -k hardware
    BATTLAB_HW_CHAMBER=modbus-tcp://CHAMBER-HOST:502 pytest tests/drivers -k hardware

Read-only except that the cycler's output is switched *off* (never on).
"""

from __future__ import annotations

import os

import pytest

from drivers.factory import open_chamber, open_cycler
from drivers.scpi.dialects import dialect_by_name

CYCLER = os.environ.get("BATTLAB_HW_CYCLER")
CHAMBER = os.environ.get("BATTLAB_HW_CHAMBER")


@pytest.mark.skipif(not CYCLER, reason="set BATTLAB_HW_CYCLER to a real cycler's URL")
def test_hardware_cycler_identity_measure_and_safe_off() -> None:
    assert CYCLER is not None
    cyc = open_cycler(CYCLER, dialect=dialect_by_name(os.environ.get("BATTLAB_HW_DIALECT", "keysight-n7951a")))
    try:
        assert cyc.identify()
        assert cyc.safe_off()
        m = cyc.measure()
        assert -1.0 < m.voltage_V < 100.0 and abs(m.current_A) < 0.1
        assert cyc.errors() == []
    finally:
        cyc.close()


@pytest.mark.skipif(not CHAMBER, reason="set BATTLAB_HW_CHAMBER to a real chamber's URL")
def test_hardware_chamber_identity_and_reading() -> None:
    assert CHAMBER is not None
    ch = open_chamber(CHAMBER)
    try:
        assert ch.identify()
        assert -80.0 < ch.read() < 200.0
    finally:
        ch.close()
