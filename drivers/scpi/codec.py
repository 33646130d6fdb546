"""SCPI codec: pure functions between commands/values and the text on the wire. No I/O here.

Header patterns use the SCPI manual notation: upper case = short form, lower case = the rest of the long
form, ``[...]`` = optional node, e.g. ``[SOURce:]CURRent[:LEVel][:IMMediate][:AMPlitude]``. The client
sends the short form of the required nodes (``CURR``); a server matches any legal spelling.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass

from drivers.errors import ReplyError

#: Standard SCPI error codes and messages (SCPI-99 vol. 2, ch. 21) that this package produces or parses.
SCPI_ERRORS: dict[int, str] = {
    0: "No error",
    -100: "Command error",
    -102: "Syntax error",
    -104: "Data type error",
    -108: "Parameter not allowed",
    -109: "Missing parameter",
    -113: "Undefined header",
    -221: "Settings conflict",
    -222: "Data out of range",
    -224: "Illegal parameter value",
    -310: "System error",
    -350: "Queue overflow",
}

_TOKEN = re.compile(r"\[(:?)([A-Za-z*]+\??)(:?)\]|(:?)([A-Za-z*]+\??)")
_NUMBER = re.compile(r"^[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?$")
_ERROR = re.compile(r'^([+-]?\d+)\s*,\s*"(.*)"$')
#: SCPI's "not a number" / overflow sentinels (9.91E37, 9.9E37).
_SCPI_NAN = (9.9e37, 9.91e37)


@dataclass(frozen=True)
class _Node:
    mnemonic: str
    optional: bool
    #: an optional node written ``[NODE:]`` (a prefix) rather than ``[:NODE]``
    prefix: bool = False

    @property
    def short(self) -> str:
        if self.mnemonic.startswith("*"):
            return self.mnemonic.upper()
        short = "".join(c for c in self.mnemonic if c.isupper() or c.isdigit())
        return short or self.mnemonic.upper()

    @property
    def long(self) -> str:
        return self.mnemonic.upper()

    def regex(self) -> str:
        alternatives = sorted({re.escape(self.long), re.escape(self.short)}, key=len, reverse=True)
        return "(?:" + "|".join(alternatives) + ")"


@functools.lru_cache(maxsize=512)
def _nodes(pattern: str) -> tuple[_Node, ...]:
    pos, nodes = 0, []
    pattern = pattern.strip()
    while pos < len(pattern):
        if pattern[pos] == ":" and (pos + 1 < len(pattern) and pattern[pos + 1] != "["):
            pos += 1
            continue
        m = _TOKEN.match(pattern, pos)
        if not m:
            raise ValueError(f"bad SCPI header pattern {pattern!r} at {pos}")
        if m.group(2):
            nodes.append(_Node(m.group(2), optional=True, prefix=bool(m.group(3)) and not m.group(1)))
        else:
            nodes.append(_Node(m.group(5), optional=False))
        pos = m.end()
    if not nodes:
        raise ValueError(f"empty SCPI header pattern {pattern!r}")
    return tuple(nodes)


@functools.lru_cache(maxsize=512)
def short_form(pattern: str) -> str:
    """The shortest legal spelling: the short forms of the required nodes (``CURR``, ``OUTP:PROT:CLE``)."""
    return ":".join(n.short for n in _nodes(pattern) if not n.optional)


@functools.lru_cache(maxsize=512)
def header_regex(pattern: str) -> re.Pattern[str]:
    """A case-insensitive regex that matches every legal spelling of the header (without ``?``)."""
    parts: list[str] = []
    at_root = True  # only [PREFIX:] nodes so far: the next required node needs no leading colon
    for node in _nodes(pattern):
        if node.optional and node.prefix:
            parts.append(f"(?:{node.regex()}:)?")
        elif node.optional:
            parts.append(f"(?::{node.regex()})?")
        else:
            parts.append(node.regex() if at_root else f":{node.regex()}")
            at_root = False
    return re.compile(f"^:?{''.join(parts)}$", re.IGNORECASE)


# -- client side: formatting ---------------------------------------------------------------------------
def format_number(value: float) -> str:
    """A number as SCPI <NRf>: enough digits to round-trip a float32-resolution setting (9 significant)."""
    if value != value or value in (float("inf"), float("-inf")):
        raise ValueError(f"cannot send {value!r} to an instrument")
    return f"{value:.9g}"


def format_bool(value: bool) -> str:
    return "1" if value else "0"


def command(pattern: str, *values: str) -> str:
    """A setting command: ``command("[SOURce:]CURRent", "1.5")`` → ``"CURR 1.5"``."""
    head = short_form(pattern)
    return f"{head} {','.join(values)}" if values else head


def query(pattern: str) -> str:
    """A query: ``query("SYSTem:ERRor[:NEXT]")`` → ``"SYST:ERR?"``."""
    return short_form(pattern) + "?"


def compound(*units: str) -> str:
    """One program message with several units: ``a;:b;:c`` (each unit from the root)."""
    return ";:".join(u.lstrip(":") for u in units)


# -- client side: parsing ------------------------------------------------------------------------------
def split_reply(reply: str, n: int, *, instrument: str, what: str) -> list[str]:
    """Split the reply to a compound query (``;``-separated) into exactly ``n`` parts."""
    parts = reply.split(";")
    if len(parts) != n:
        raise ReplyError(instrument, f"expected {n} ';'-separated values for {what}", reply=reply)
    return [p.strip() for p in parts]


def parse_number(reply: str, *, instrument: str, what: str) -> float:
    """Parse <NR1>/<NR2>/<NR3>; reject text, NaN/inf and SCPI's 9.9E37 overflow sentinel."""
    text = reply.strip()
    if not _NUMBER.match(text):
        raise ReplyError(instrument, f"{what}: not a number", reply=reply)
    value = float(text)
    if abs(value) in _SCPI_NAN:
        raise ReplyError(instrument, f"{what}: the instrument returned SCPI's not-a-number", reply=reply)
    return value


def parse_int(reply: str, *, instrument: str, what: str) -> int:
    value = parse_number(reply, instrument=instrument, what=what)
    if value != int(value):
        raise ReplyError(instrument, f"{what}: not an integer", reply=reply)
    return int(value)


def parse_bool(reply: str, *, instrument: str, what: str) -> bool:
    text = reply.strip().upper()
    if text in ("1", "ON", "+1"):
        return True
    if text in ("0", "OFF", "+0"):
        return False
    raise ReplyError(instrument, f"{what}: not a boolean (0/1/ON/OFF)", reply=reply)


def parse_error(reply: str, *, instrument: str) -> tuple[int, str]:
    """Parse a ``SYST:ERR?`` reply such as ``-113,"Undefined header"`` into ``(code, message)``."""
    m = _ERROR.match(reply.strip())
    if not m:
        raise ReplyError(instrument, 'error queue reply is not <code>,"<message>"', reply=reply)
    return int(m.group(1)), m.group(2)


def parse_idn(reply: str, *, instrument: str) -> tuple[str, str, str, str]:
    """Parse ``*IDN?``: ``(manufacturer, model, serial, firmware)``."""
    parts = [p.strip() for p in reply.split(",")]
    if len(parts) != 4 or not parts[0] or not parts[1]:
        raise ReplyError(instrument, "*IDN? reply is not <maker>,<model>,<serial>,<firmware>", reply=reply)
    return parts[0], parts[1], parts[2], parts[3]


# -- server side -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ProgramUnit:
    """One unit of a program message: ``header`` (no leading ``:``, no ``?``), its arguments, query flag."""

    header: str
    args: tuple[str, ...]
    is_query: bool


def parse_program_message(line: str) -> list[ProgramUnit]:
    """Split ``CURR 1.5;:SYST:ERR?`` into program units (every unit taken from the root)."""
    units: list[ProgramUnit] = []
    for raw in _split_outside_quotes(line.strip(), ";"):
        raw = raw.strip()
        if not raw:
            continue
        head, _, rest = raw.partition(" ")
        head = head.strip().lstrip(":")
        is_query = head.endswith("?")
        if is_query:
            head = head[:-1]
        args = tuple(a.strip() for a in _split_outside_quotes(rest.strip(), ",")) if rest.strip() else ()
        units.append(ProgramUnit(head, args, is_query))
    return units


def _split_outside_quotes(text: str, sep: str) -> list[str]:
    out, cur, quote = [], [], ""
    for c in text:
        if quote:
            cur.append(c)
            if c == quote:
                quote = ""
        elif c in "\"'":
            quote = c
            cur.append(c)
        elif c == sep:
            out.append("".join(cur))
            cur = []
        else:
            cur.append(c)
    out.append("".join(cur))
    return out


def format_error(code: int, message: str | None = None) -> str:
    """An error-queue reply: ``format_error(-113)`` → ``-113,"Undefined header"``."""
    text = message if message is not None else SCPI_ERRORS.get(code, "Unknown error")
    return f'{code:+d},"{text}"' if code else '+0,"No error"'


def format_nr3(value: float, digits: int = 6) -> str:
    """A response number in NR3 (``+1.234560E+00``), as Keysight supplies send them."""
    return f"{value:+.{digits}E}"


def parse_value(text: str) -> float:
    """Server side: parse a numeric argument (raises ValueError)."""
    text = text.strip()
    if not _NUMBER.match(text):
        raise ValueError(text)
    return float(text)


def parse_bool_arg(text: str) -> bool:
    """Server side: parse a boolean argument (raises ValueError)."""
    t = text.strip().upper()
    if t in ("1", "ON"):
        return True
    if t in ("0", "OFF"):
        return False
    raise ValueError(text)
