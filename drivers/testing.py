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
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from pathlib import Path

from drivers.errors import CommunicationError, InstrumentFault

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
