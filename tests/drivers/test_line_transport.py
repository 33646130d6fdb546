"""The pyserial line adapter over a real loopback socket: timeouts, disconnects, logging, port locks."""

from __future__ import annotations

import logging
import socket
import threading
import time
from collections.abc import Iterator

import pytest

from drivers.errors import CommunicationError, ReplyError
from drivers.transport import LineAdapter, port_lock, with_retries


class TinyServer:
    """Replies ``echo:<line>``; ``silent`` → no reply; ``late`` → ``late-reply`` once ``release`` is set (after the
    host gave up on it; ``sent_late`` then); ``close`` → closes the connection. ``heard`` is set when ``silent`` or
    ``late`` arrives."""

    def __init__(self) -> None:
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen()
        self.sock.settimeout(0.1)
        self.port = self.sock.getsockname()[1]
        self.stop = threading.Event()
        self.connections = 0
        self.heard = threading.Event()
        self.release = threading.Event()
        self.sent_late = threading.Event()
        self.thread = threading.Thread(target=self.run, daemon=True)
        self.thread.start()

    def run(self) -> None:
        while not self.stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except TimeoutError:
                continue
            self.connections += 1
            threading.Thread(target=self.serve, args=(conn,), daemon=True).start()

    def serve(self, conn: socket.socket) -> None:
        conn.settimeout(0.1)
        buf = b""
        while not self.stop.is_set():
            try:
                data = conn.recv(4096)
            except TimeoutError:
                continue
            if not data:
                break
            buf += data
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                if line == b"silent":
                    self.heard.set()
                    continue
                if line == b"late":
                    self.heard.set()
                    self.release.wait(5.0)
                    try:
                        conn.sendall(b"late-reply\n")
                    except OSError:  # the host closed this connection already
                        pass
                    finally:
                        self.sent_late.set()
                    continue
                if line == b"close":
                    conn.close()
                    return
                if line == b"split":  # a reply arriving in pieces
                    conn.sendall(b"par")
                    time.sleep(0.02)
                    conn.sendall(b"ts\nnext\n")
                    continue
                if line == b"latin":
                    conn.sendall(b"caf\xe9\n")
                    continue
                conn.sendall(b"echo:" + line + b"\r\n")
        conn.close()


@pytest.fixture
def server() -> Iterator[TinyServer]:
    srv = TinyServer()
    yield srv
    srv.stop.set()
    srv.thread.join(1)
    srv.sock.close()


def test_query_strips_terminators_and_reads_split_replies(server: TinyServer) -> None:
    a = LineAdapter(f"socket://127.0.0.1:{server.port}", timeout_s=1.0)
    assert a.query("hello") == "echo:hello"
    assert a.query("split") == "parts"
    assert a.query("x") == "next"  # the buffered second line is the next reply (stale data is not lost)
    a.close()


def test_timeout_is_bounded_and_names_the_command(server: TinyServer) -> None:
    """The query was heard and never answered: a timeout naming the command; the connection works after recover."""
    a = LineAdapter(f"socket://127.0.0.1:{server.port}", name="dut", timeout_s=0.2)
    with pytest.raises(CommunicationError, match="dut: no reply to 'silent' within 0.2 s"):
        a.query("silent")
    assert server.heard.is_set()  # sent and received: the error is the missing reply, not the link
    a.recover()  # reconnects: the connection works again
    assert a.query("again") == "echo:again"
    assert server.connections == 2
    a.close()


def test_a_reply_after_the_timeout_is_not_taken_for_the_next_one(server: TinyServer) -> None:
    """The reply comes only after the host gave up on it (the server waits for that event): recover drops it with
    the old connection, and the next query reads its own reply."""
    a = LineAdapter(f"socket://127.0.0.1:{server.port}", name="dut", timeout_s=0.2)
    with pytest.raises(CommunicationError, match="dut: no reply to 'late' within 0.2 s"):
        a.query("late")
    assert server.heard.is_set()
    a.recover()
    server.release.set()  # the late reply goes out on the old connection
    assert server.sent_late.wait(5.0)
    assert a.query("again") == "echo:again"
    assert a.query("more") == "echo:more"
    a.close()


def test_disconnect_is_a_communication_error_and_reconnects(server: TinyServer) -> None:
    a = LineAdapter(f"socket://127.0.0.1:{server.port}", timeout_s=1.0)
    with pytest.raises(CommunicationError, match="connection lost"):
        a.query("close")
    assert a.query("back") == "echo:back"  # reopened on the next exchange
    a.close()


def test_non_ascii_reply_is_a_reply_error(server: TinyServer) -> None:
    a = LineAdapter(f"socket://127.0.0.1:{server.port}", timeout_s=1.0)
    with pytest.raises(ReplyError, match="not ascii"):
        a.query("latin")
    a.close()


def test_cannot_open_names_the_port() -> None:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()  # nothing listens there now
    with pytest.raises(CommunicationError) as err:
        LineAdapter(f"socket://127.0.0.1:{port}", timeout_s=0.5)
    message = str(err.value)  # the port once, then why
    assert message.startswith(f"socket://127.0.0.1:{port}: cannot connect: ") and message.count(str(port)) == 1


def test_every_exchange_is_logged_in_one_place(server: TinyServer, caplog: pytest.LogCaptureFixture) -> None:
    a = LineAdapter(f"socket://127.0.0.1:{server.port}", name="dut", timeout_s=0.2)
    with caplog.at_level(logging.DEBUG, logger="drivers.io"):
        a.query("ping")
        with pytest.raises(CommunicationError):
            a.query("silent")
    messages = [r.getMessage() for r in caplog.records if r.name == "drivers.io"]
    assert any("dut > 'ping' < 'echo:ping'" in m for m in messages)
    assert any("dut > 'silent' < None" in m and "FAILED" in m for m in messages)
    a.close()


def test_one_lock_per_port(server: TinyServer) -> None:
    url = f"socket://127.0.0.1:{server.port}"
    a, b = LineAdapter(url, timeout_s=1.0), LineAdapter(url, timeout_s=1.0)
    assert a.lock is b.lock is port_lock(url)
    assert port_lock("socket://127.0.0.1:1") is not a.lock
    results: list[str] = []

    def worker(adapter: LineAdapter, tag: str) -> None:
        for i in range(50):
            results.append(adapter.query(f"{tag}{i}"))

    threads = [threading.Thread(target=worker, args=(ad, t)) for ad, t in ((a, "a"), (b, "b"))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10)
    assert sorted(results) == sorted([f"echo:a{i}" for i in range(50)] + [f"echo:b{i}" for i in range(50)])
    a.close()
    b.close()


def test_with_retries_recovers_then_gives_up() -> None:
    calls: list[int] = []
    recovered: list[int] = []

    def flaky() -> str:
        calls.append(1)
        if len(calls) < 3:
            raise CommunicationError("dut", "timeout")
        return "ok"

    assert with_retries("dut", "op", flaky, retries=2, recover=lambda: recovered.append(1)) == "ok"
    assert (len(calls), len(recovered)) == (3, 2)

    def always() -> str:
        raise ReplyError("dut", "garbled", reply="##")

    with pytest.raises(ReplyError, match="dut: op failed after 2 attempts: garbled") as info:
        with_retries("dut", "op", always, retries=1)
    assert info.value.reply == "##"
