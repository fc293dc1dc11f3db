"""The user-space delay proxy forwards bytes intact and in order, and never delivers them sooner
than its delay each way (plus one round trip for a new connection's handshake)."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator

import pytest

from benchmarks.delay_proxy import DelayProxy

DELAY = 0.03


@pytest.fixture
def echo() -> Iterator[tuple[str, int]]:
    server = socket.create_server(("127.0.0.1", 0))

    def serve() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            with conn:
                while data := conn.recv(65536):
                    conn.sendall(data)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    yield server.getsockname()[:2]
    server.shutdown(socket.SHUT_RDWR)  # wakes the blocked accept()
    server.close()
    thread.join(5)


def _exchange(sock: socket.socket, payload: bytes) -> bytes:
    sock.sendall(payload)
    got = b""
    while len(got) < len(payload):
        got += sock.recv(65536)
    return got


def test_bytes_arrive_intact_and_no_sooner_than_the_delay(echo: tuple[str, int]) -> None:
    payload = bytes(range(256)) * 1000  # 256 KB: several chunks, order matters
    with DelayProxy(*echo, DELAY) as proxy:
        # from before the connect: the handshake's round trip is counted from the proxy's accept
        start = time.monotonic()
        with socket.create_connection(("127.0.0.1", proxy.port)) as sock:
            assert _exchange(sock, b"first") == b"first"
            first = time.monotonic() - start
            start = time.monotonic()
            assert _exchange(sock, payload) == payload
            second = time.monotonic() - start
    assert first >= 4 * DELAY  # handshake round trip + request + answer
    assert second >= 2 * DELAY


def test_a_refused_target_closes_the_client() -> None:
    dead = socket.create_server(("127.0.0.1", 0))
    port = dead.getsockname()[1]
    dead.close()
    with DelayProxy("127.0.0.1", port, DELAY) as proxy, socket.create_connection(("127.0.0.1", proxy.port)) as sock:
        sock.settimeout(5)
        assert sock.recv(10) == b""
