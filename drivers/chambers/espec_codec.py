"""Espec P-300 text protocol codec (pure functions, no I/O).

Checked against Espec North America's ChamberConnectLibrary (MIT; ``p300.py``, ``especinteract.py``):
commands end in CR LF; TCP port 10001 (a serial-to-Ethernet adaptor on the P-300); ``TEMP?`` replies
``PV,SP,upper,lower`` (e.g. ``23.5,25.0,50.0,-40.0``); ``TEMP, S25.0`` sets the set point; ``MODE, CONSTANT``
runs constant mode; ``MON?`` replies ``temperature,humidity,mode,alarm count`` (humidity empty without a
humidity system); ``ALARM?`` replies ``count[,code…]``; an error reply is ``NA:<message>`` (the library's
table of messages). The ``OK:`` acknowledgement of a setting follows the interface specification we work from and
was **not** seen in the library (which only tests for ``NA:``): the driver relies on the ``OK:`` prefix alone;
the virtual P-300 echoes the command after it.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

from drivers.errors import InstrumentFault, ReplyError

#: ``NA:`` messages and their meaning (ChamberConnectLibrary's table, abridged).
NA_MESSAGES: dict[str, str] = {
    "CMD ERR": "unrecognised command",
    "ADDR ERR": "bad address",
    "PARA ERR": "parameter missing or unrecognisable",
    "DATA OUT OF RANGE": "data not within the valid range",
    "PROTECT ON": "controller data protection is enabled on the panel",
    "CONT NOT READY-1": "chamber does not support this function",
    "CONT NOT READY-3": "command not supported by this controller",
    "CHB NOT READY": "could not act on the command",
    "INVALID REQ": "unsupported function",
}

MODES = ("OFF", "STANDBY", "CONSTANT", "RUN")
_NUM = r"[+-]?\d+(?:\.\d+)?"
_TEMP = re.compile(rf"^({_NUM}),({_NUM}),({_NUM}),({_NUM})$")
_MON = re.compile(rf"^({_NUM}),({_NUM})?,([A-Z ]+),(\d+)$")
_SET = re.compile(rf"^TEMP\s*,\s*((?:[SHL]{_NUM}\s*)+)$", re.IGNORECASE)
_SET_PART = re.compile(rf"([SHL])({_NUM})", re.IGNORECASE)


@dataclass(frozen=True)
class TempStatus:
    """``TEMP?``: process value, set point, upper and lower absolute limits / °C."""

    pv_C: float
    sp_C: float
    upper_C: float
    lower_C: float


@dataclass(frozen=True)
class MonStatus:
    """``MON?``: temperature / °C, humidity / %RH (None without), mode, number of active alarms."""

    T_C: float
    humidity: float | None
    mode: str
    alarms: int


# -- client side --------------------------------------------------------------------------------------------
def set_point_command(T_C: float) -> str:
    """``TEMP, S25.0`` (0.1 °C resolution)."""
    return f"TEMP, S{T_C:.1f}"


def mode_command(mode: str) -> str:
    """``MODE, CONSTANT``."""
    mode = mode.upper()
    if mode not in MODES[:3]:
        raise ValueError(f"mode must be one of {MODES[:3]}, got {mode!r}")
    return f"MODE, {mode}"


def check_na(reply: str, *, instrument: str, command: str) -> None:
    """Raise :class:`InstrumentFault` for an ``NA:`` reply, naming the command and the meaning."""
    if reply.startswith("NA:"):
        msg = reply[3:].strip()
        meaning = NA_MESSAGES.get(msg, "no description")
        raise InstrumentFault(instrument, f"{command!r} refused: {msg} ({meaning})", reply=reply)


def parse_ok(reply: str, *, instrument: str, command: str) -> None:
    """A setting's acknowledgement: ``OK:…``; ``NA:…`` raises InstrumentFault; anything else ReplyError."""
    check_na(reply, instrument=instrument, command=command)
    if not reply.startswith("OK:"):
        raise ReplyError(instrument, f"expected OK: or NA: after {command!r}", reply=reply)


def parse_temp(reply: str, *, instrument: str) -> TempStatus:
    check_na(reply, instrument=instrument, command="TEMP?")
    m = _TEMP.match(reply.strip())
    if not m:
        raise ReplyError(instrument, "TEMP? reply is not PV,SP,upper,lower", reply=reply)
    return TempStatus(*(float(g) for g in m.groups()))


def parse_mon(reply: str, *, instrument: str) -> MonStatus:
    check_na(reply, instrument=instrument, command="MON?")
    m = _MON.match(reply.strip())
    if not m:
        raise ReplyError(instrument, "MON? reply is not temperature,humidity,mode,alarms", reply=reply)
    humidity = float(m.group(2)) if m.group(2) else None
    return MonStatus(float(m.group(1)), humidity, m.group(3).strip(), int(m.group(4)))


def parse_alarm(reply: str, *, instrument: str) -> list[int]:
    """``ALARM?``: ``0`` or ``n,code1,…,coden``."""
    check_na(reply, instrument=instrument, command="ALARM?")
    parts = [p.strip() for p in reply.strip().split(",")]
    try:
        values = [int(p) for p in parts]
    except ValueError:
        raise ReplyError(instrument, "ALARM? reply is not count[,code...]", reply=reply) from None
    if values[0] != len(values) - 1:
        raise ReplyError(instrument, "ALARM? count does not match the codes", reply=reply)
    return values[1:]


# -- server side --------------------------------------------------------------------------------------------
def format_temp(status: TempStatus) -> str:
    return f"{status.pv_C:.1f},{status.sp_C:.1f},{status.upper_C:.1f},{status.lower_C:.1f}"


def format_mon(status: MonStatus) -> str:
    hum = "" if status.humidity is None else f"{status.humidity:.0f}"
    return f"{status.T_C:.1f},{hum},{status.mode},{status.alarms}"


def format_alarm(codes: list[int]) -> str:
    return ",".join(str(v) for v in [len(codes), *codes])


def parse_set_temp(command: str) -> dict[str, float] | None:
    """``TEMP, S25.0 H50.0 L-40.0`` → ``{"S": 25.0, "H": 50.0, "L": -40.0}``; None if not a TEMP setting."""
    m = _SET.match(command.strip())
    if not m:
        return None
    return {k.upper(): float(v) for k, v in _SET_PART.findall(m.group(1))}


def parse_mode(command: str) -> str | None:
    """``MODE, CONSTANT`` → ``"CONSTANT"``; None if not a MODE setting."""
    m = re.match(r"^MODE\s*,\s*([A-Z]+)$", command.strip(), re.IGNORECASE)
    return m.group(1).upper() if m else None
