"""Instrument URL parsing: the documented forms, and a one-line InputError naming a bad URL."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from drivers.urls import parse_url
from protocols.errors import InputError


@pytest.mark.parametrize(
    ("url", "scheme", "host", "port", "device", "options"),
    [
        ("socket://127.0.0.1:5025", "socket", "127.0.0.1", 5025, None, {}),
        ("/dev/ttyUSB0", "serial", None, None, "/dev/ttyUSB0", {}),
        ("/dev/ttyUSB0?baud=115200", "serial", None, None, "/dev/ttyUSB0", {"baud": "115200"}),
        ("COM3", "serial", None, None, "COM3", {}),
        ("modbus-tcp://127.0.0.7:502", "modbus-tcp", "127.0.0.7", 502, None, {}),
        ("modbus-tcp://localhost", "modbus-tcp", "localhost", 502, None, {}),
        ("modbus-tcp://127.0.0.1:1502?unit=3", "modbus-tcp", "127.0.0.1", 1502, None, {"unit": "3"}),
        ("modbus-rtu:///dev/ttyUSB1?baud=38400", "modbus-rtu", None, None, "/dev/ttyUSB1", {"baud": "38400"}),
        ("modbus-rtu+socket://127.0.0.1:4001", "modbus-rtu+socket", "127.0.0.1", 4001, None, {}),
        ("espec://127.0.0.1:10001", "espec", "127.0.0.1", 10001, None, {}),
        ("espec://localhost", "espec", "localhost", 10001, None, {}),
        ("espec:///dev/ttyS0?baud=9600", "espec", None, None, "/dev/ttyS0", {"baud": "9600"}),
        ("virtual", "virtual", None, None, None, {}),
    ],
)
def test_documented_urls(
    url: str, scheme: str, host: str | None, port: int | None, device: str | None, options: dict[str, str]
) -> None:
    u = parse_url(url)
    assert (u.scheme, u.host, u.port, u.device, u.options) == (scheme, host, port, device, options)


def test_pyserial_url() -> None:
    assert parse_url("socket://127.0.0.1:5025").pyserial_url == "socket://127.0.0.1:5025"
    assert parse_url("espec://127.0.0.1:9").pyserial_url == "socket://127.0.0.1:9"
    assert parse_url("modbus-rtu:///dev/ttyUSB1").pyserial_url == "/dev/ttyUSB1"


@pytest.mark.parametrize(
    ("url", "why"),
    [
        ("", "empty"),
        ("http://127.0.0.1:80", "unknown scheme 'http'"),
        ("socket://127.0.0.1", "no port"),
        ("socket://127.0.0.1:99999", "bad port"),
        ("modbus-rtu://127.0.0.1:502", "needs a device path"),
        ("modbus-tcp://127.0.0.1?slave=1", "unknown option"),
        ("espec://127.0.0.1:10001/x", "unexpected path"),
        ("ttyUSB0", "not a device path"),
        ("espec:///tmp/x", "not a serial device path"),
    ],
)
def test_bad_urls_name_the_url(url: str, why: str) -> None:
    with pytest.raises(InputError) as info:
        parse_url(url)
    message = str(info.value)
    assert repr(url) in message and why in message and "\n" not in message


def test_bad_option_values_are_input_errors() -> None:
    with pytest.raises(InputError, match="unit='x' is not an integer"):
        parse_url("modbus-tcp://127.0.0.1?unit=x").int_option("unit", 1)


@given(st.integers(1, 65535), st.integers(1, 254))
def test_socket_urls_round_trip(port: int, last_octet: int) -> None:
    url = f"socket://127.0.0.{last_octet}:{port}"  # loopback only, even in parse-only tests
    u = parse_url(url)
    assert (u.host, u.port, u.pyserial_url) == (f"127.0.0.{last_octet}", port, url)
