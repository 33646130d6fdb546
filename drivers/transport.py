"""Transports: text-line connections over pyserial, one lock per port, every exchange logged in one place.

Concurrency model of ``drivers`` (clients): **blocking I/O with timeouts, threads allowed**. Every physical
port has exactly one :class:`threading.RLock` (:func:`port_lock`, keyed by the port's URL), held for a whole
command/reply exchange, so two drivers sharing an RS-485 bus or a socket never interleave. The virtual
tester's servers use the same model (a thread per connection, blocking sockets); only pymodbus's server
runs on asyncio, in its own thread with its own loop (``drivers.virtual.modbus_server``).

All exchanges go through :func:`log_exchange` (logger ``drivers.io``, level DEBUG).
"""

from __future__ import annotations

import contextlib
import logging
import socket
import threading
import time
from collections.abc import Callable
from typing import Protocol, TypeVar

import serial

from drivers.errors import CommunicationError, ReplyError

log = logging.getLogger("drivers.io")
_log_drivers = logging.getLogger("drivers")

_PORT_LOCKS: dict[str, threading.RLock] = {}
_PORT_LOCKS_GUARD = threading.Lock()

T = TypeVar("T")


def port_lock(key: str) -> threading.RLock:
    """The one lock of the port ``key`` (a pyserial URL or device path), created on first use."""
    with _PORT_LOCKS_GUARD:
        lock = _PORT_LOCKS.get(key)
        if lock is None:
            lock = _PORT_LOCKS[key] = threading.RLock()
        return lock


def log_exchange(name: str, sent: object, received: object, elapsed_s: float, note: str = "") -> None:
    """Log one exchange (the one place where instrument I/O is logged)."""
    if log.isEnabledFor(logging.DEBUG):
        log.debug("%s > %r < %r (%.3f ms)%s", name, sent, received, elapsed_s * 1e3, f" {note}" if note else "")


class TextAdapter(Protocol):
    """What a text-protocol driver needs from its connection (pymeasure's "adapter")."""

    name: str
    #: the read timeout / s, which the driver may change while connected (None: the adapter has none)
    timeout_s: float | None

    def write(self, command: str) -> None:
        """Send one command line (no reply expected)."""
        ...

    def query(self, command: str) -> str:
        """Send one command line and return the reply line, without its terminator."""
        ...

    def recover(self) -> None:
        """Resynchronise after a failed exchange (reconnect a socket, flush a serial port)."""
        ...

    def close(self) -> None: ...


class LineAdapter:
    """A line-oriented connection through pyserial's ``serial_for_url``.

    ``port`` is a device path (``/dev/ttyUSB0``) or a pyserial URL (``socket://127.0.0.1:5025``).
    ``timeout_s`` bounds every read; a missing reply raises :class:`CommunicationError`.
    """

    def __init__(
        self,
        port: str,
        *,
        name: str | None = None,
        timeout_s: float = 2.0,
        baudrate: int = 9600,
        write_terminator: str = "\n",
        read_terminator: str = "\n",
        encoding: str = "ascii",
        open_now: bool = True,
    ) -> None:
        if not timeout_s > 0:
            raise ValueError(f"timeout_s must be > 0, got {timeout_s}")
        self.port = port
        self.name = name or port
        self.timeout_s = float(timeout_s)
        self.baudrate = baudrate
        self.write_terminator = write_terminator.encode(encoding)
        self.read_terminator = read_terminator.encode(encoding)
        self.encoding = encoding
        self.lock = port_lock(port)
        self._serial: serial.SerialBase | None = None
        self._buffer = bytearray()
        self._is_socket = port.startswith("socket://")
        if open_now:
            self.open()

    # -- connection -------------------------------------------------------------------------------------
    def open(self) -> None:
        with self.lock:
            if self._serial is not None:
                return
            try:
                self._serial = serial.serial_for_url(self.port, baudrate=self.baudrate, timeout=self.timeout_s)
            except (serial.SerialException, OSError, ValueError) as exc:
                # pyserial says "Could not open port <port>: <why>"; the error names the port once
                why = str(exc).removeprefix(f"Could not open port {self.port}: ")
                raise CommunicationError(self.name, f"cannot connect: {why}") from exc
            self._buffer.clear()

    def close(self) -> None:
        with self.lock:
            ser, self._serial = self._serial, None
            self._buffer.clear()
            if ser is None:
                return
            sock = getattr(ser, "_socket", None) if self._is_socket else None
            if sock is not None:
                # pyserial's socket close() sleeps 0.3 s "for quick reconnects"; at 1000x that is five
                # virtual minutes of a retry, so the socket is closed here directly.
                ser._socket = None
                ser.is_open = False
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)
                with contextlib.suppress(OSError):
                    sock.close()
                return
            with contextlib.suppress(serial.SerialException, OSError):
                ser.close()

    def recover(self) -> None:
        """Drop stale bytes: reconnect a socket; on a serial line wait briefly and flush the input."""
        with self.lock:
            if self._is_socket:
                self.close()
                self.open()
            else:
                time.sleep(min(0.2, self.timeout_s))
                self._buffer.clear()
                if self._serial is not None:
                    try:
                        self._serial.reset_input_buffer()
                    except (serial.SerialException, OSError):
                        self.close()
                        self.open()

    # -- I/O --------------------------------------------------------------------------------------------
    def write(self, command: str) -> None:
        with self.lock:
            t0 = time.perf_counter()
            self._send(command)
            log_exchange(self.name, command, None, time.perf_counter() - t0)

    def query(self, command: str) -> str:
        with self.lock:
            t0 = time.perf_counter()
            self._send(command)
            try:
                reply = self._read_line(command)
            except CommunicationError as exc:
                log_exchange(self.name, command, None, time.perf_counter() - t0, f"FAILED: {exc}")
                raise
            log_exchange(self.name, command, reply, time.perf_counter() - t0)
            return reply

    def _send(self, command: str) -> None:
        if self._serial is None:
            self.open()
        assert self._serial is not None
        try:
            data = command.encode(self.encoding) + self.write_terminator
        except UnicodeEncodeError as exc:
            raise ValueError(f"{self.name}: command {command!r} is not {self.encoding}") from exc
        try:
            self._serial.write(data)
        except (serial.SerialException, OSError) as exc:
            self.close()
            raise CommunicationError(self.name, f"send of {command!r} failed: {exc}") from exc

    def _read_line(self, command: str) -> str:
        ser = self._serial
        assert ser is not None
        term = self.read_terminator
        deadline = time.monotonic() + self.timeout_s
        try:
            while term not in self._buffer:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    raise CommunicationError(
                        self.name,
                        f"no reply to {command!r} within {self.timeout_s:g} s",
                        reply=bytes(self._buffer).decode(self.encoding, "replace") or None,
                    )
                # Block for the first byte, then take whatever else has arrived in one read
                # (pyserial's read_until reads byte by byte: ~7x slower on a socket).
                ser.timeout = remaining
                first = ser.read(1)
                if not first:
                    continue
                self._buffer += first
                ser.timeout = 0
                self._buffer += ser.read(65536)
        except (serial.SerialException, OSError) as exc:
            self.close()
            raise CommunicationError(self.name, f"connection lost waiting for the reply to {command!r}: {exc}") from exc
        finally:
            if self._serial is not None:
                self._serial.timeout = self.timeout_s
        index = self._buffer.index(term)
        line = bytes(self._buffer[:index])
        del self._buffer[: index + len(term)]
        try:
            return line.decode(self.encoding).rstrip("\r")
        except UnicodeDecodeError:
            raise ReplyError(self.name, f"reply to {command!r} is not {self.encoding}", reply=line) from None


def with_retries(
    name: str,
    what: str,
    attempt: Callable[[], T],
    *,
    retries: int,
    recover: Callable[[], None] | None = None,
    backoff_s: float = 0.0,
) -> T:
    """Run an idempotent exchange, retrying ``retries`` times on :class:`CommunicationError`.

    ``recover`` runs between attempts (e.g. reconnect); ``backoff_s`` doubles after each failure.
    The last CommunicationError is re-raised with the attempt count in its message. Failed attempts are logged at
    INFO (``--verbose``): the caller reports the failure that matters.
    """
    last: CommunicationError | None = None
    delay = backoff_s
    for n in range(retries + 1):
        try:
            return attempt()
        except CommunicationError as exc:
            last = exc
            _log_drivers.info("%s: %s failed (attempt %d of %d): %s", name, what, n + 1, retries + 1, exc)
            if n == retries:
                break
            if delay > 0:
                time.sleep(delay)
                delay *= 2
            if recover is not None:
                try:
                    recover()
                except CommunicationError as rexc:
                    last = rexc
    assert last is not None
    raise type(last)(name, f"{what} failed after {retries + 1} attempts: {last.detail}", reply=last.reply) from last
