"""The context broker's HTTP server (engine/context_broker/http_server.py) on real sockets, with a
small WSGI app: keep-alive after 204, pipelining answered in order, inline and pooled requests,
chunked bodies, ``Expect: 100-continue``, HEAD, the limits answered with Orion's JSON body, a
half-closed client answered, slow and non-reading clients that stop nobody else, idle
connections closed, the connection limit."""

from __future__ import annotations

import json
import socket
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

import pytest

from engine.context_broker import http_server
from engine.context_broker.http_server import HttpServer
from engine.netutil import free_port

HOST = "127.0.0.1"


def app(environ: dict[str, Any], start_response: Any) -> list[bytes]:
    """Echoes what the server gave it; ``/slow`` sleeps, ``/nocontent`` is a 204, ``/big`` is 1 MB."""
    path = environ["PATH_INFO"]
    body = environ["wsgi.input"].read()
    if path == "/nocontent":
        start_response("204 NO CONTENT", [("Content-Type", "text/html; charset=utf-8")])
        return [b""]
    if path == "/slow":
        time.sleep(float(environ["QUERY_STRING"] or "0.5"))
    if path == "/big":
        start_response("200 OK", [("Content-Type", "application/octet-stream")])
        return [b"x" * (1024 * 1024)]
    if path == "/boom":
        raise RuntimeError("a bug below the app's own error handling")
    answer = json.dumps({"method": environ["REQUEST_METHOD"], "path": path,
                         "query": environ["QUERY_STRING"], "length": environ.get("CONTENT_LENGTH"),
                         "te": environ.get("HTTP_TRANSFER_ENCODING"), "body": body.decode("latin-1"),
                         "thread": threading.current_thread().name,
                         "x": environ.get("HTTP_X_THING")}).encode()
    start_response("200 OK", [("Content-Type", "application/json"), ("Content-Length", str(len(answer)))])
    return [answer]


def inline(environ: dict[str, Any]) -> bool:
    return environ["PATH_INFO"].startswith("/inline")


@contextmanager
def serving(srv: HttpServer) -> Iterator[HttpServer]:
    """``srv`` running in a thread; stopped and closed after."""
    thread = threading.Thread(target=srv.run, kwargs={"stop_signals": ()}, daemon=True)
    thread.start()
    try:
        yield srv
    finally:
        srv.stop()
        thread.join(10)
        assert not thread.is_alive()
        srv.close()


@pytest.fixture
def server(request: pytest.FixtureRequest) -> Iterator[HttpServer]:
    options = getattr(request, "param", {})
    with serving(HttpServer(app, HOST, free_port(), threads=4, inline=inline, **options)) as srv:
        yield srv


def connect(srv: HttpServer) -> socket.socket:
    sock = socket.create_connection((HOST, srv.port), timeout=10)
    return sock


def read_answer(sock: socket.socket, buf: bytearray, head_request: bool = False) -> tuple[int, dict[str, str], bytes]:
    """One answer from ``sock`` (``buf`` keeps what was read beyond it)."""
    while b"\r\n\r\n" not in buf:
        chunk = sock.recv(65536)
        if not chunk:
            raise ConnectionError(f"closed before an answer; got {bytes(buf)[:200]!r}")
        buf += chunk
    end = buf.index(b"\r\n\r\n")
    head = bytes(buf[:end]).decode("latin-1").split("\r\n")
    del buf[:end + 4]
    status = int(head[0].split()[1])
    headers: dict[str, str] = {}
    for line in head[1:]:
        name, _, value = line.partition(":")
        assert name.lower() not in headers, f"header {name} sent twice: {head}"
        headers[name.lower()] = value.strip()
    length = 0 if head_request or status in (100, 204, 304) else int(headers.get("content-length", "0"))
    while len(buf) < length:
        chunk = sock.recv(65536)
        if not chunk:
            raise ConnectionError("closed mid-body")
        buf += chunk
    body = bytes(buf[:length])
    del buf[:length]
    return status, headers, body


def closed(sock: socket.socket, deadline: float = 5.0) -> bool:
    sock.settimeout(deadline)
    try:
        while sock.recv(65536):
            pass
        return True
    except (ConnectionResetError, BrokenPipeError):
        return True
    except socket.timeout:
        return False


def request(method: str, path: str, body: bytes = b"", extra: str = "") -> bytes:
    return (f"{method} {path} HTTP/1.1\r\nHost: x\r\n{extra}Content-Length: {len(body)}\r\n\r\n"
            .encode() + body)


def test_keep_alive_after_204_and_pipelined_answers_in_order(server: HttpServer) -> None:
    with connect(server) as sock:
        buf = bytearray()
        sock.sendall(request("PATCH", "/nocontent", b"{}"))
        status, headers, _ = read_answer(sock, buf)
        assert status == 204 and "content-length" not in headers and headers.get("connection") != "close"
        # five requests in one write, mixing the event loop (inline) and the worker threads
        paths = ["/slow?0.2", "/inline/a", "/b", "/slow?0.05", "/inline/c"]
        sock.sendall(b"".join(request("POST", p, p.encode()) for p in paths))
        answers = [json.loads(read_answer(sock, buf)[2]) for _ in paths]
    assert [a["body"] for a in answers] == paths
    assert answers[1]["thread"] == "MainThread" or not answers[1]["thread"].startswith("cb-http")
    assert answers[2]["thread"].startswith("cb-http")


def test_environ_chunked_body_headers_and_query(server: HttpServer) -> None:
    with connect(server) as sock:
        buf = bytearray()
        sock.sendall(b"POST /a%20b?x=1&y=%2F HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n"
                     b"X-Thing: one\r\nX-Thing: two\r\nX_Thing: spoofed\r\n\r\n"
                     b"5\r\nhello\r\n6\r\n world\r\n0\r\n\r\n")
        status, _, body = read_answer(sock, buf)
    echoed = json.loads(body)
    assert status == 200
    assert echoed["path"] == "/a b" and echoed["query"] == "x=1&y=%2F"
    assert echoed["body"] == "hello world" and echoed["length"] == "11" and echoed["te"] is None
    assert echoed["x"] == "one,two"  # X_Thing is dropped: it could pose as X-Thing


def test_expect_100_continue_and_head(server: HttpServer) -> None:
    with connect(server) as sock:
        buf = bytearray()
        sock.sendall(b"PUT /x HTTP/1.1\r\nHost: x\r\nExpect: 100-continue\r\nContent-Length: 3\r\n\r\n")
        assert read_answer(sock, buf)[0] == 100
        sock.sendall(b"abc")
        status, _, body = read_answer(sock, buf)
        assert status == 200 and json.loads(body)["body"] == "abc"
        sock.sendall(b"HEAD /x HTTP/1.1\r\nHost: x\r\n\r\n")
        status, headers, body = read_answer(sock, buf, head_request=True)
        assert status == 200 and body == b"" and int(headers["content-length"]) > 0
        sock.sendall(request("GET", "/x"))  # the HEAD left no body bytes behind
        assert read_answer(sock, buf)[0] == 200


@pytest.mark.parametrize("raw, status, error", [
    (b"NOT HTTP AT ALL\r\n\r\n", 400, "BadRequest"),
    (b"GET / HTTP/1.1\r\nHost: x\r\nContent-Length: abc\r\n\r\n", 400, "BadRequest"),
    (b"POST / HTTP/1.1\r\nHost: x\r\nContent-Length: 99999999999\r\n\r\n", 413, "RequestEntityTooLarge"),
    (b"GET / HTTP/1.1\r\nHost: x\r\nX-Big: " + b"a" * (http_server.MAX_HEADER_BYTES + 10) + b"\r\n\r\n",
     431, "BadRequest"),
    (b"GET /" + b"a" * (http_server.MAX_HEADER_BYTES + 10) + b" HTTP/1.1\r\n\r\n", 414, "BadRequest"),
])
def test_refusals_are_orion_json_then_close(server: HttpServer, raw: bytes, status: int, error: str) -> None:
    with connect(server) as sock:
        sock.sendall(raw)
        got, headers, body = read_answer(sock, bytearray())
        assert (got, json.loads(body)["error"]) == (status, error), body
        assert headers["connection"] == "close" and headers["content-type"] == "application/json"
        assert closed(sock)


def test_chunked_body_over_the_limit_is_413(server: HttpServer, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(http_server, "MAX_BODY_READ", 1000)
    with connect(server) as sock:
        sock.sendall(b"POST / HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n"
                     + b"".join(b"200\r\n" + b"z" * 512 + b"\r\n" for _ in range(4)))
        status, _, body = read_answer(sock, bytearray())
    assert status == 413 and json.loads(body)["error"] == "RequestEntityTooLarge"


def test_a_bug_below_the_app_is_a_logged_500(server: HttpServer, caplog: pytest.LogCaptureFixture) -> None:
    with connect(server) as sock:
        buf = bytearray()
        sock.sendall(request("GET", "/boom"))
        status, _, body = read_answer(sock, buf)
        assert status == 500 and json.loads(body)["error"] == "InternalServerError"
        sock.sendall(request("GET", "/after"))  # the connection still serves
        assert read_answer(sock, buf)[0] == 200
    assert "a bug below the app" in caplog.text


def test_half_closed_client_gets_its_answers(server: HttpServer) -> None:
    with connect(server) as sock:
        sock.sendall(request("POST", "/a", b"1") + request("POST", "/inline/b", b"2"))
        sock.shutdown(socket.SHUT_WR)
        buf = bytearray()
        bodies = [json.loads(read_answer(sock, buf)[2])["body"] for _ in range(2)]
        assert bodies == ["1", "2"] and closed(sock)


def test_connection_close_is_honoured(server: HttpServer) -> None:
    with connect(server) as sock:
        sock.sendall(request("GET", "/a", extra="Connection: close\r\n") + request("GET", "/never"))
        status, headers, _ = read_answer(sock, bytearray())
        assert status == 200 and headers["connection"] == "close" and closed(sock)


def test_stalled_and_non_reading_clients_stop_nobody(server: HttpServer) -> None:
    """Clients stalled mid-header and mid-body, and one that sends requests for 1 MB answers without
    reading any: a well-behaved client is answered at once."""
    socks = []
    try:
        for _ in range(16):
            s = connect(server)
            s.sendall(b"POST /x HTTP/1.1\r\nHost: x\r\nContent-Length: 100\r\n\r\n{\"id\"")
            socks.append(s)
            s = connect(server)
            s.sendall(b"GET /x HTTP/1.1\r\nHo")
            socks.append(s)
        hog = connect(server)
        hog.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
        socks.append(hog)
        hog.sendall(request("GET", "/big") * 64)
        deadline = time.monotonic() + 10
        while not any(c.write_paused for c in list(server.connections)):  # the hog's buffers are full
            assert time.monotonic() < deadline, "the server never paused writing to the hog"
            time.sleep(0.01)
        with connect(server) as sock:
            started = time.monotonic()
            sock.sendall(request("GET", "/ok"))
            status, _, _ = read_answer(sock, bytearray())
            waited = time.monotonic() - started
    finally:
        for s in socks:
            s.close()
    assert status == 200 and waited < 1.0, waited


@pytest.mark.parametrize("server", [{"idle_timeout": 0.5}], indirect=True)
def test_idle_connections_are_closed(server: HttpServer) -> None:
    with connect(server) as idle, connect(server) as stalled:
        stalled.sendall(b"GET /x HTTP/1.1\r\nHo")
        assert closed(idle, deadline=5.0) and closed(stalled, deadline=5.0)


@pytest.mark.parametrize("server", [{"max_connections": 3}], indirect=True)
def test_connections_over_the_limit_get_503(server: HttpServer) -> None:
    held = [connect(server) for _ in range(3)]
    try:
        for s in held:  # each one is served, so each is counted
            s.sendall(request("GET", "/a"))
            assert read_answer(s, bytearray())[0] == 200
        with connect(server) as extra:
            status, _, body = read_answer(extra, bytearray())
            assert status == 503 and json.loads(body)["error"] == "ServiceUnavailable"
    finally:
        for s in held:
            s.close()


def test_port_in_use_is_an_os_error() -> None:
    with socket.socket() as taken:
        taken.bind((HOST, 0))
        taken.listen()
        with pytest.raises(OSError):
            HttpServer(app, HOST, taken.getsockname()[1], threads=1)


@pytest.mark.parametrize("server", [{"max_body": 1000}], indirect=True)
def test_a_body_over_max_body_is_read_dropped_and_answered_413(server: HttpServer) -> None:
    """The request before it is answered; the big one never reaches the app (its bytes are not
    kept); the client, still sending, reads Orion's 413, then the connection closes."""
    with connect(server) as sock:
        buf = bytearray()
        sock.sendall(request("POST", "/first", b"1") + request("POST", "/big", b"x" * 5000))
        status, _, body = read_answer(sock, buf)
        assert status == 200 and json.loads(body)["path"] == "/first"
        status, headers, body = read_answer(sock, buf)
        assert status == 413 and headers["connection"] == "close"
        assert json.loads(body) == {"error": "RequestEntityTooLarge",
                                    "description": "payload size: 5000 bytes, max size supported: 1000 bytes"}
        assert closed(sock)
    with connect(server) as sock:  # chunked: the same once its chunks pass the limit
        sock.sendall(b"POST /big HTTP/1.1\r\nHost: x\r\nTransfer-Encoding: chunked\r\n\r\n"
                     + b"".join(b"200\r\n" + b"z" * 512 + b"\r\n" for _ in range(4)) + b"0\r\n\r\n")
        status, _, body = read_answer(sock, bytearray())
        assert status == 413 and "2048 bytes" in json.loads(body)["description"]
