"""SCPI codec: header forms, number/boolean/error parsing, program messages (pure functions)."""

from __future__ import annotations

import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.errors import ReplyError
from drivers.scpi import codec
from drivers.scpi.dialects import BATTLAB_VIRTUAL, ITECH_IT6000, KEYSIGHT_N7900


@pytest.mark.parametrize(
    ("pattern", "short", "accepted", "rejected"),
    [
        (
            "[SOURce:]CURRent[:LEVel][:IMMediate][:AMPlitude]",
            "CURR",
            ["CURR", "curr", "SOUR:CURR", "SOURCE:CURRENT:LEVEL", "CURR:LEV:IMM:AMP", ":CURR"],
            ["CURRE", "CURR:LEVE", "SOUR", "LEV", "CURR:AMPL"],
        ),
        ("[SOURce:]FUNCtion", "FUNC", ["FUNC", "SOUR:FUNC", "function"], ["FUN", "SOUR:"]),
        ("OUTPut[:STATe]", "OUTP", ["OUTP", "OUTPUT:STAT", "outp:state"], ["STAT", "OUT"]),
        (
            "MEASure[:SCALar]:VOLTage[:DC]",
            "MEAS:VOLT",
            ["MEAS:VOLT", "MEAS:SCAL:VOLT:DC"],
            ["MEASVOLT", "VOLT"],
        ),
        ("OUTPut:PROTection:WDOG:DELay", "OUTP:PROT:WDOG:DEL", ["OUTP:PROT:WDOG:DELAY"], ["OUTP:WDOG:DEL"]),
        ("*IDN", "*IDN", ["*IDN", "*idn"], ["IDN"]),
    ],
)
def test_header_forms(pattern: str, short: str, accepted: list[str], rejected: list[str]) -> None:
    assert codec.short_form(pattern) == short
    regex = codec.header_regex(pattern)
    assert all(regex.match(h) for h in accepted), [h for h in accepted if not regex.match(h)]
    assert not any(regex.match(h) for h in rejected), [h for h in rejected if regex.match(h)]


@pytest.mark.parametrize("dialect", [BATTLAB_VIRTUAL, KEYSIGHT_N7900, ITECH_IT6000])
def test_every_dialect_header_matches_its_own_short_form(dialect: object) -> None:
    for prop in dialect.properties:  # type: ignore[attr-defined]
        assert codec.header_regex(prop.header).match(codec.short_form(prop.header)), prop.name


def test_commands_and_queries() -> None:
    assert codec.command("[SOURce:]CURRent[:LEVel]", "1.5") == "CURR 1.5"
    assert codec.query("SYSTem:ERRor[:NEXT]") == "SYST:ERR?"
    assert codec.compound("CURR 1", ":SYST:ERR?") == "CURR 1;:SYST:ERR?"


@pytest.mark.parametrize(
    ("reply", "value"),
    [("+1.234560E+00", 1.23456), ("3.7", 3.7), ("-2", -2.0), (" 42 ", 42.0), (".5", 0.5), ("1e-3", 1e-3)],
)
def test_parse_number(reply: str, value: float) -> None:
    assert codec.parse_number(reply, instrument="x", what="v") == value


@pytest.mark.parametrize("reply", ["", "abc", "1,2", "nan", "inf", "+9.910000E+37", "9.9E37", "1.2.3", "#1.0"])
def test_parse_number_rejects_garbage_naming_instrument_and_reply(reply: str) -> None:
    with pytest.raises(ReplyError) as info:
        codec.parse_number(reply, instrument="cycler[x]", what="voltage")
    assert "cycler[x]" in str(info.value) and repr(reply) in str(info.value)


@given(st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=1e6))
def test_number_format_round_trips_to_nine_digits(value: float) -> None:
    back = codec.parse_number(codec.format_number(value), instrument="x", what="v")
    assert math.isclose(back, value, rel_tol=1e-8, abs_tol=1e-300)


@given(st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=1e6))
def test_nr3_responses_parse(value: float) -> None:
    assert math.isclose(
        codec.parse_number(codec.format_nr3(value), instrument="x", what="v"),
        value,
        rel_tol=1e-6,
        abs_tol=1e-300,
    )


def test_format_number_refuses_nan() -> None:
    with pytest.raises(ValueError):
        codec.format_number(float("nan"))


def test_booleans_and_integers() -> None:
    assert codec.parse_bool("1", instrument="x", what="b") is True
    assert codec.parse_bool("OFF", instrument="x", what="b") is False
    assert codec.parse_int("+2048", instrument="x", what="i") == 2048
    with pytest.raises(ReplyError):
        codec.parse_bool("2", instrument="x", what="b")
    with pytest.raises(ReplyError):
        codec.parse_int("1.5", instrument="x", what="i")


def test_error_queue_replies() -> None:
    assert codec.parse_error('-113,"Undefined header"', instrument="x") == (-113, "Undefined header")
    assert codec.parse_error('+0,"No error"', instrument="x") == (0, "No error")
    assert codec.format_error(-113) == '-113,"Undefined header"'
    assert codec.format_error(0) == '+0,"No error"'
    with pytest.raises(ReplyError, match="error queue reply"):
        codec.parse_error("-113 Undefined header", instrument="x")


def test_idn() -> None:
    assert codec.parse_idn("Keysight Technologies,N7951A,MY1,B.01", instrument="x")[1] == "N7951A"
    with pytest.raises(ReplyError):
        codec.parse_idn("just text", instrument="x")


def test_split_reply() -> None:
    assert codec.split_reply("1;2;3", 3, instrument="x", what="m") == ["1", "2", "3"]
    with pytest.raises(ReplyError, match="expected 2"):
        codec.split_reply("1;2;3", 2, instrument="x", what="m")


def test_program_message_parsing() -> None:
    units = codec.parse_program_message('CURR 1.5;:SYST:ERR?;:OUTP:PROT:CLE;*IDN?;DISP:TEXT "a;b,c"')
    assert [(u.header, u.args, u.is_query) for u in units] == [
        ("CURR", ("1.5",), False),
        ("SYST:ERR", (), True),
        ("OUTP:PROT:CLE", (), False),
        ("*IDN", (), True),
        ("DISP:TEXT", ('"a;b,c"',), False),
    ]
