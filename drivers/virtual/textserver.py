"""A threaded TCP server for line-based text protocols (SCPI, Espec), with fault injection.

Concurrency: one accept thread plus one thread per connection, blocking sockets with short timeouts so
that :meth:`LineServer.stop` ends every thread within a bounded time. The handler runs in the connection's
thread; it takes the lab's lock itself.
"""

from __future__ import annotations

import contextlib
import logging
import socket
import threading
import time
from collections.abc import Callable

from drivers.virtual.faults import Fault, FaultInjector

log = logging.getLogger("drivers.virtual")

_POLL_S = 0.1


class LineServer:
    """Serve ``handler(line) -> reply | None`` on ``host:port`` (port 0: a free port)."""

    def __init__(
        self,
        name: str,
        handler: Callable[[str], str | None],
        *,
        host: str = "127.0.0.1",
        port: int = 0,
        read_terminator: str = "\n",
        write_terminator: str = "\n",
        faults: FaultInjector | None = None,
        encoding: str = "ascii",
    ) -> None:
        self.name = name
        self.handler = handler
        self.host = host
        self.requested_port = port
        self.read_terminator = read_terminator.encode(encoding)
        self.write_terminator = write_terminator.encode(encoding)
        self.faults = faults or FaultInjector()
        self.encoding = encoding
        self._sock: socket.socket | None = None
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._conns: set[socket.socket] = set()
        self._lock = threading.Lock()
        self.messages = 0

    @property
    def port(self) -> int:
        if self._sock is None:
            raise RuntimeError(f"{self.name}: not started")
        return int(self._sock.getsockname()[1])

    @property
    def url(self) -> str:
        return f"socket://{self.host}:{self.port}"

    def start(self) -> None:
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            sock.bind((self.host, self.requested_port))
        except OSError:
            sock.close()
            raise
        sock.listen(8)
        sock.settimeout(_POLL_S)
        self._sock = sock
        thread = threading.Thread(target=self._accept_loop, name=f"{self.name}-accept", daemon=True)
        thread.start()
        self._threads.append(thread)
        log.info("%s listening on %s:%d", self.name, self.host, self.port)

    def stop(self, timeout_s: float = 2.0) -> None:
        self._stop.set()
        with self._lock:
            conns = list(self._conns)
        for conn in conns:
            _close(conn)
        if self._sock is not None:
            _close(self._sock)
        deadline = time.monotonic() + timeout_s
        for thread in self._threads:
            thread.join(max(0.0, deadline - time.monotonic()))

    def disconnect_all(self) -> None:
        """Close every client connection (a server-side disconnect)."""
        with self._lock:
            conns = list(self._conns)
        for conn in conns:
            _close(conn)

    def _accept_loop(self) -> None:
        assert self._sock is not None
        while not self._stop.is_set():
            try:
                conn, _addr = self._sock.accept()
            except TimeoutError:
                continue
            except OSError:
                break
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            conn.settimeout(_POLL_S)
            with self._lock:
                self._conns.add(conn)
            thread = threading.Thread(target=self._serve, args=(conn,), name=f"{self.name}-conn", daemon=True)
            thread.start()
            self._threads = [t for t in self._threads if t.is_alive()] + [thread]

    def _serve(self, conn: socket.socket) -> None:
        buf = bytearray()
        term = self.read_terminator
        try:
            while not self._stop.is_set():
                try:
                    data = conn.recv(65536)
                except TimeoutError:
                    continue
                except OSError:
                    return
                if not data:
                    return
                buf += data
                while term in buf:
                    i = buf.index(term)
                    raw = bytes(buf[:i])
                    del buf[: i + len(term)]
                    if not self._message(conn, raw.decode(self.encoding, "replace").strip("\r\n")):
                        return
        finally:
            with self._lock:
                self._conns.discard(conn)
            _close(conn)

    def _message(self, conn: socket.socket, line: str) -> bool:
        """Handle one message; False ends the connection."""
        self.messages += 1
        fault = self.faults.next_fault()
        if fault is Fault.DROP:
            return True
        if fault is Fault.DISCONNECT:
            log.info("%s: injected disconnect", self.name)
            return False
        try:
            reply = self.handler(line)
        except Exception:  # a handler bug must not kill the server thread silently
            log.exception("%s: handler failed on %r", self.name, line)
            return True
        if reply is None or fault is Fault.LOSE_REPLY:
            return True
        if fault is Fault.DELAY:
            self._stop.wait(self.faults.config.delay_s)
        if fault is Fault.GARBLE:
            reply = self.faults.garble_text(reply)
        try:
            conn.sendall(reply.encode(self.encoding, "replace") + self.write_terminator)
        except OSError:
            return False
        return True


def _close(sock: socket.socket) -> None:
    with contextlib.suppress(OSError):
        sock.shutdown(socket.SHUT_RDWR)
    with contextlib.suppress(OSError):
        sock.close()
