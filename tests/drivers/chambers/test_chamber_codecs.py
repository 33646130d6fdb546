"""Watlow F4T register encoding and Espec P-300 text codec (pure functions)."""

from __future__ import annotations

import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.chambers import espec_codec as ec
from drivers.chambers import watlow_codec as wc
from drivers.errors import InstrumentFault, ReplyError


def test_f4t_register_map() -> None:
    assert (wc.PROCESS_VALUE, wc.SET_POINT) == (2820, 2782)
    assert wc.loop_register(wc.SET_POINT, 2) == 2942
    with pytest.raises(ValueError):
        wc.loop_register(wc.SET_POINT, 5)


@pytest.mark.parametrize(
    ("value", "registers"),
    [(25.0, [0x0000, 0x41C8]), (23.5, [0x0000, 0x41BC]), (-40.0, [0x0000, 0xC220]), (0.1, [0xCCCD, 0x3DCC])],
)
def test_f4t_float_low_word_first(value: float, registers: list[int]) -> None:
    assert wc.encode_float(value) == registers
    assert wc.decode_float(registers, instrument="f4t", what="pv") == pytest.approx(value, rel=1e-7)


@given(st.floats(width=32, allow_nan=False, allow_infinity=False))
def test_f4t_float_round_trip(value: float) -> None:
    assert wc.decode_float(wc.encode_float(value), instrument="f4t", what="v") == value


def test_f4t_bad_registers() -> None:
    with pytest.raises(ReplyError, match="two 16-bit registers"):
        wc.decode_float([1], instrument="f4t", what="pv")
    nan = list(struct.unpack("<HH", struct.pack("<f", float("nan"))))
    with pytest.raises(ReplyError, match="not a finite number"):
        wc.decode_float(nan, instrument="f4t", what="pv")


def test_f4t_strings_and_units() -> None:
    assert wc.decode_string(wc.encode_string("F4T1", 6)) == "F4T1"
    assert wc.c_to_f(25.0) == pytest.approx(77.0) and wc.f_to_c(77.0) == pytest.approx(25.0)


def test_espec_commands() -> None:
    assert ec.set_point_command(25) == "TEMP, S25.0"
    assert ec.set_point_command(-12.345) == "TEMP, S-12.3"
    assert ec.mode_command("constant") == "MODE, CONSTANT"
    with pytest.raises(ValueError):
        ec.mode_command("RUN")


def test_espec_replies() -> None:
    assert ec.parse_temp("23.5,25.0,50.0,-40.0", instrument="p300") == ec.TempStatus(23.5, 25.0, 50.0, -40.0)
    assert ec.parse_mon("24.1,,CONSTANT,0", instrument="p300") == ec.MonStatus(24.1, None, "CONSTANT", 0)
    assert ec.parse_mon("24.1,55,RUN PAUSE,2", instrument="p300").humidity == 55.0
    assert ec.parse_alarm("0", instrument="p300") == []
    assert ec.parse_alarm("2,3,25", instrument="p300") == [3, 25]
    ec.parse_ok("OK: TEMP, S25.0", instrument="p300", command="TEMP, S25.0")


@pytest.mark.parametrize("reply", ["23.5,25.0,50.0", "23.5;25.0;50.0;-40.0", "abc", "OK: TEMP, S25.0"])
def test_espec_garbled_temp(reply: str) -> None:
    with pytest.raises(ReplyError, match="TEMP\\? reply"):
        ec.parse_temp(reply, instrument="p300")


def test_espec_na_errors_name_command_and_meaning() -> None:
    with pytest.raises(InstrumentFault, match=r"'TEMP, S999.0' refused: DATA OUT OF RANGE \(data not within"):
        ec.parse_ok("NA:DATA OUT OF RANGE", instrument="p300", command="TEMP, S999.0")
    with pytest.raises(InstrumentFault, match="CMD ERR"):
        ec.parse_temp("NA:CMD ERR", instrument="p300")
    with pytest.raises(ReplyError, match="expected OK: or NA:"):
        ec.parse_ok("#K: TEMP", instrument="p300", command="TEMP, S25.0")
    with pytest.raises(ReplyError, match="count does not match"):
        ec.parse_alarm("2,3", instrument="p300")


def test_espec_server_side_parsing() -> None:
    assert ec.parse_set_temp("TEMP, S25.0") == {"S": 25.0}
    assert ec.parse_set_temp("temp,S-10.5 H50 L-40") == {"S": -10.5, "H": 50.0, "L": -40.0}
    assert ec.parse_set_temp("TEMP?") is None
    assert ec.parse_mode("MODE, CONSTANT") == "CONSTANT"
    assert ec.format_temp(ec.TempStatus(23.456, 25, 150, -40)) == "23.5,25.0,150.0,-40.0"
