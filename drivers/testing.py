"""Test doubles that replay recorded command/response pairs (pymeasure's ProtocolAdapter idea).

A recording is a text file of exchanges::

    # comment
    > *IDN?
    < Keysight Technologies,N7951A,MY1234,B.01.02
    > OUTP 0;:SYST:ERR?
    < +0,"No error"
    > FOO 1                 (a write: no "<" line follows)

For Modbus register access (:class:`ReplayRegisters`): ``> R 2820 2`` / ``< 0 16828`` for a read,
``> W 2782 0 16840`` / ``< OK`` for a write, ``< EXC 2`` for a Modbus exception reply.

The replaying adapter fails on the first unexpected command and :meth:`assert_all_used` fails on pairs
that were never exercised, so a recording cannot silently go stale.

:func:`contract_problems` checks a driver against its interface (:mod:`drivers.interfaces`).
"""

from __future__ import annotations

import inspect
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from drivers.clock import RealClock
from drivers.errors import CommunicationError, InstrumentFault, NotSupported
from drivers.interfaces import Chamber, ChamberCapabilities, Cycler, CyclerCapabilities
from protocols.errors import InputError

Pair = tuple[str, str | None]


def parse_recording(text: str, source: str = "<recording>") -> list[Pair]:
    """Parse ``> command`` / ``< reply`` lines into pairs; the reply is None for a write."""
    pairs: list[Pair] = []
    for lineno, raw in enumerate(text.splitlines(), 1):
        line = raw.rstrip("\n")
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        if line.startswith("> "):
            pairs.append((line[2:], None))
        elif line.startswith("< ") or line == "<":
            if not pairs or pairs[-1][1] is not None:
                raise ValueError(f"{source}:{lineno}: reply without a command")
            pairs[-1] = (pairs[-1][0], line[2:])
        else:
            raise ValueError(f"{source}:{lineno}: expected '> command' or '< reply', got {line!r}")
    return pairs


def load_recording(path: str | Path) -> list[Pair]:
    path = Path(path)
    return parse_recording(path.read_text(encoding="utf-8"), str(path))


class _Replay:
    def __init__(self, pairs: Iterable[Pair], name: str) -> None:
        self.pairs = list(pairs)
        self.name = name
        self.position = 0

    def _next(self, sent: str, expect_reply: bool) -> str | None:
        if self.position >= len(self.pairs):
            raise AssertionError(f"{self.name}: unexpected extra command {sent!r} (recording exhausted)")
        command, reply = self.pairs[self.position]
        if command != sent:
            raise AssertionError(f"{self.name}: pair {self.position + 1}: sent {sent!r}, recording expects {command!r}")
        if expect_reply and reply is None:
            raise AssertionError(f"{self.name}: pair {self.position + 1}: {sent!r} expects a reply, recording has none")
        if not expect_reply and reply is not None:
            raise AssertionError(
                f"{self.name}: pair {self.position + 1}: {sent!r} sent as a write, recording has reply {reply!r}"
            )
        self.position += 1
        return reply

    def assert_all_used(self) -> None:
        if self.position != len(self.pairs):
            unused = self.pairs[self.position :]
            raise AssertionError(f"{self.name}: {len(unused)} recorded pair(s) never used, first {unused[0]!r}")

    def close(self) -> None:
        pass


class ReplayAdapter(_Replay):
    """A :class:`drivers.transport.TextAdapter` that replays a recording. ``<TIMEOUT>`` simulates no reply."""

    #: a recording has no read timeout to change
    timeout_s: float | None = None

    def __init__(self, pairs: Iterable[Pair], name: str = "replay") -> None:
        super().__init__(pairs, name)
        self.recoveries = 0

    def write(self, command: str) -> None:
        self._next(command, expect_reply=False)

    def query(self, command: str) -> str:
        reply = self._next(command, expect_reply=True)
        assert reply is not None
        if reply == "<TIMEOUT>":
            raise CommunicationError(self.name, f"no reply to {command!r} (recorded timeout)")
        return reply

    def recover(self) -> None:
        self.recoveries += 1


class ReplayRegisters(_Replay):
    """A :class:`drivers.chambers.modbus.RegisterAdapter` replaying ``R``/``W`` pairs (any number base)."""

    #: a recording is never retried
    retries = 0

    def __init__(self, pairs: Iterable[Pair], name: str = "replay") -> None:
        def normal(command: str) -> str:
            op, *numbers = command.split()
            return " ".join([op, *(str(int(v, 0)) for v in numbers)])

        super().__init__([(normal(c), r) for c, r in pairs], name)

    def read(self, address: int, count: int) -> list[int]:
        reply = self._next(f"R {address} {count}", expect_reply=True)
        assert reply is not None
        if reply.startswith("EXC"):
            raise InstrumentFault(self.name, f"Modbus exception {reply[3:].strip()}")
        return [int(v, 0) for v in reply.split()]

    def write(self, address: int, values: list[int]) -> None:
        reply = self._next(" ".join(["W", str(address), *(str(v) for v in values)]), expect_reply=True)
        if reply is not None and reply.startswith("EXC"):
            raise InstrumentFault(self.name, f"Modbus exception {reply[3:].strip()}")
        if reply != "OK":
            raise AssertionError(f"{self.name}: write reply must be OK or EXC n, got {reply!r}")


def wait_until(predicate: Callable[[], bool], timeout_s: float, poll_s: float = 0.005) -> bool:
    """Poll ``predicate`` for at most ``timeout_s`` real seconds (every wait in a test is bounded)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(poll_s)
    return predicate()


# -- the driver contract ---------------------------------------------------------------------------------------
_SPECS: dict[str, tuple[type, type]] = {
    "cycler": (Cycler, CyclerCapabilities),
    "chamber": (Chamber, ChamberCapabilities),
}
_SKIP = {"__init__", "__subclasshook__", "__class_getitem__", "__init_subclass__", "__new__"}

#: each optional cycler operation, the capability that declares it, and a call that would use it
_CYCLER_OPTIONAL: tuple[tuple[str, str, Callable[[Any], Any]], ...] = (
    ("low_voltage_cutoff", "set_voltage_limits(2.5, 4.2)", lambda d: d.set_voltage_limits(2.5, 4.2)),
    ("temperature_limit", "set_temperature_limit(318.15)", lambda d: d.set_temperature_limit(318.15)),
    ("watchdog", "set_watchdog(60.0)", lambda d: d.set_watchdog(60.0)),
    ("clear_protection", "clear_protection()", lambda d: d.clear_protection()),
)


def protocol_members(protocol: type) -> dict[str, Any]:
    """The members a :class:`typing.Protocol` declares (its own and its protocol bases'): name → function, property,
    or the annotation of a data member."""
    members: dict[str, Any] = {}
    for base in reversed(protocol.__mro__):
        if base is object or not getattr(base, "_is_protocol", False) or base.__name__ in ("Protocol", "Generic"):
            continue
        members.update(dict.fromkeys(base.__dict__.get("__annotations__", {}), "attribute"))
        for name, value in base.__dict__.items():
            if (
                name not in _SKIP
                and not name.startswith("_")
                and (inspect.isfunction(value) or isinstance(value, property))
            ):
                members[name] = value
    return members


def _signature_problems(name: str, wanted: Any, got: Any) -> list[str]:
    try:
        want, have = inspect.signature(wanted), inspect.signature(got)
    except (TypeError, ValueError):
        return []
    want_params = [p for p in want.parameters.values() if p.name != "self"]
    have_params = {p.name: p for p in have.parameters.values() if p.name != "self"}
    problems = []
    for p in want_params:
        q = have_params.pop(p.name, None)
        if q is None:
            problems.append(f"{name}: no parameter {p.name!r}")
        elif q.kind != p.kind and q.kind not in (p.POSITIONAL_OR_KEYWORD,):
            problems.append(f"{name}: parameter {p.name!r} is {q.kind.description}, wanted {p.kind.description}")
        elif p.default is not p.empty and q.default is p.empty:
            problems.append(f"{name}: parameter {p.name!r} needs a default")
    for q in have_params.values():
        if q.default is q.empty and q.kind not in (q.VAR_POSITIONAL, q.VAR_KEYWORD):
            problems.append(f"{name}: extra parameter {q.name!r} without a default")
    return problems


def contract_problems(device: object, role: str) -> list[str]:
    """What ``device`` lacks to be a ``role`` (``cycler`` or ``chamber``) by :mod:`drivers.interfaces`; empty if it
    conforms.

    Checked: every member of the interface is there, methods take the interface's parameters, ``capabilities`` has
    the role's type, and each optional operation agrees with it: one the capabilities leave out raises
    :class:`NotSupported` (a cycler without a clock gives the host's :class:`RealClock`), one they declare raises
    neither NotSupported nor InputError for a value in range. ``device`` must sit on a link that fails every
    exchange (e.g. a :class:`ReplayAdapter` with no pairs): operations it declares are called and may fail there.
    """
    protocol, caps_type = _SPECS[role]
    cls = type(device)
    problems: list[str] = []
    for name, wanted in protocol_members(protocol).items():
        if not hasattr(device, name):
            problems.append(f"{cls.__name__} has no {name}")
            continue
        if inspect.isfunction(wanted):
            got = getattr(device, name)
            if not callable(got):
                problems.append(f"{cls.__name__}.{name} is not callable")
            else:
                problems += [f"{cls.__name__}.{p}" for p in _signature_problems(name, wanted, got)]
    if problems:
        return problems
    caps = device.capabilities  # type: ignore[attr-defined]
    if not isinstance(caps, caps_type):
        return [f"{cls.__name__}.capabilities is {type(caps).__name__}, not {caps_type.__name__}"]
    if not isinstance(device.name, str) or not isinstance(device.retries, int):  # type: ignore[attr-defined]
        problems.append(f"{cls.__name__}: name must be a str and retries an int")
    checks = list(_CYCLER_OPTIONAL) if role == "cycler" else []
    checks.append(("link_timeout", "setting link_timeout_s", _set_link_timeout))
    for flag, what, use in checks:
        declared = getattr(caps, flag)
        try:
            use(device)
        except (NotSupported, InputError) as exc:
            if declared:
                problems.append(f"{cls.__name__}: {what} raises {type(exc).__name__} but capabilities.{flag} is True")
            if isinstance(exc, NotSupported) or declared:
                continue
            problems.append(f"{cls.__name__}: {what} raises InputError, not NotSupported, without capabilities.{flag}")
            continue
        except Exception:  # declared and tried: failing on the silent link is allowed
            pass
        if not declared:
            problems.append(f"{cls.__name__}: {what} does not raise NotSupported but capabilities.{flag} is False")
    if role == "cycler" and not caps.clock:
        try:
            clock = device.clock()  # type: ignore[attr-defined]
        except Exception as exc:
            problems.append(f"{cls.__name__}: clock() without the clock capability raised {exc!r}")
        else:
            if not isinstance(clock, RealClock):
                problems.append(f"{cls.__name__}: clock() without the clock capability is not the host's RealClock")
    return problems


def _set_link_timeout(device: Any) -> None:
    old = device.link_timeout_s
    device.link_timeout_s = 1.0
    if old is not None:
        device.link_timeout_s = old
