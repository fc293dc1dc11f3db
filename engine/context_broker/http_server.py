"""The context broker's HTTP/1.1 server: asyncio for the connections, httptools (llhttp, the
parser of Node.js) for the bytes, the WSGI app for the answers.

Why not waitress (used before): under one interpreter lock, its event loop, its task objects and
the hand-off of every request to a worker thread cost ~3x the NGSI write itself, so the broker
topped out near 1,500 updates/s, and lower with more clients. Here:

- **Hot writes run on the event loop** (``inline(environ)`` true, the fast path's plain
  ``PATCH``/``POST``/``PUT`` of :mod:`.fastpath`): the write is ~0.2 ms of CPU, less than a thread
  hand-off, and the store serializes writes anyway. Everything else (queries, Flask's routes,
  subscriptions) runs in a pool of ``threads`` worker threads, so a long query does not hold
  the loop.
- **Slow clients hold nothing**: a request is read whole, asynchronously, before anything runs it;
  a client that stalls mid-header or mid-body costs a buffer, not a worker. Connections idle for
  ``idle_timeout`` s are closed. A client that does not read its answers is paused (no more of
  its requests are run, its socket is not read) until it drains them.
- **Limits**: headers over ``MAX_HEADER_BYTES`` get 431; a body over ``max_body`` (the app's
  1 MB) is read and thrown away, not kept, then answered 413 (so a client still sending sees the
  answer, not a reset) — up to ``MAX_BODY_READ``, past which the 413 comes at once; bytes that are
  not HTTP/1.x get 400 — each as Orion's JSON error body, then the connection is closed. So a
  connection holds at most ``max_body`` of request body in memory. At most ``max_connections``
  connections: the next ones get 503.
- HTTP/1.1 keep-alive (also after 204, which waitress closed), pipelining answered in order,
  ``Expect: 100-continue``, chunked request bodies (given to the app with their length, as
  waitress did), ``HEAD`` without a body.
- **TLS** (``ssl_context``, the context broker's ``pk:tls``): the listener speaks HTTPS only;
  asyncio wraps each accepted connection and runs its handshake without blocking the loop, closing
  it after ``HANDSHAKE_TIMEOUT`` s; a plain HTTP client gets no answer.
"""

from __future__ import annotations

import asyncio
import io
import json
import logging
import signal
import socket
import ssl
import sys
import time
from collections import deque
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from email.utils import formatdate
from typing import Any
from urllib.parse import unquote_to_bytes

import httptools

log = logging.getLogger("engine.context_broker.http")
MAX_BODY_READ = 16 * 1024 * 1024  # bodies up to this are read (and thrown away) before their 413
MAX_BODY = 16 * 1024 * 1024  # default ``max_body``; the context broker passes its 1 MB
MAX_HEADER_BYTES = 64 * 1024
MAX_PIPELINED = 32  # requests read ahead on one connection before its socket is paused
IDLE_TIMEOUT = 120.0
#: Seconds a TLS client has to finish its handshake (asyncio runs it on the loop, so a slow or
#: silent client holds nothing meanwhile; past this its connection is closed).
HANDSHAKE_TIMEOUT = 10.0
MAX_CONNECTIONS = 1000
SERVER_NAME = "plantkg-context-broker"

WSGIApp = Callable[[dict[str, Any], Callable[..., Any]], Iterable[bytes]]
Inline = Callable[[dict[str, Any]], bool]


class _Refusal(Exception):
    """A request the server answers itself (status, Orion error name, description) and closes."""

    def __init__(self, status: str, error: str, description: str) -> None:
        super().__init__(description)
        self.status, self.error, self.description = status, error, description


def _error_answer(refusal: _Refusal) -> bytes:
    body = json.dumps({"error": refusal.error, "description": refusal.description}).encode()
    return (f"HTTP/1.1 {refusal.status}\r\nServer: {SERVER_NAME}\r\nDate: {_date()}\r\n"
            f"Content-Type: application/json\r\nContent-Length: {len(body)}\r\n"
            "Connection: close\r\n\r\n").encode("latin-1") + body


_date_cache: list[Any] = [0, ""]


def _date() -> str:
    now = int(time.time())
    if _date_cache[0] != now:
        _date_cache[:] = [now, formatdate(now, usegmt=True)]
    return str(_date_cache[1])


class _Request:
    __slots__ = ("url", "headers", "header_bytes", "body", "body_size", "method", "version",
                 "keep_alive", "chunked", "too_large")

    def __init__(self) -> None:
        self.url = b""
        self.headers: list[tuple[bytes, bytes]] = []
        self.header_bytes = 0
        self.body: list[bytes] = []
        self.body_size = 0
        self.too_large = False  # over max_body: its bytes are dropped, the answer is a 413
        self.method = "GET"
        self.version = "1.1"
        self.keep_alive = True
        self.chunked = False


def run_wsgi(app: WSGIApp, environ: dict[str, Any]) -> tuple[str, list[tuple[str, str]], bytes]:
    """Call ``app`` and return its status, headers and whole body (the answers are small; the
    largest, ``/plantkg/v1/graph``, is built whole by the app anyway)."""
    answer: list[Any] = []

    def start_response(status: str, headers: list[tuple[str, str]], exc_info: Any = None) -> Callable[[bytes], None]:
        if exc_info is not None and answer:
            raise exc_info[1].with_traceback(exc_info[2])
        answer[:] = [status, headers]
        return _no_write

    result = app(environ, start_response)
    try:
        body = b"".join(result)
    finally:
        close = getattr(result, "close", None)
        if close is not None:
            close()
    return answer[0], answer[1], body


def _no_write(_data: bytes) -> None:
    raise RuntimeError("the context broker's server does not support WSGI write()")


class _Connection(asyncio.Protocol):
    """One client connection: parse, queue, run in order, answer."""

    def __init__(self, server: HttpServer) -> None:
        self.server = server
        self.transport: asyncio.Transport | None = None
        self.parser = httptools.HttpRequestParser(self)
        self.current: _Request | None = None
        self.queue: deque[_Request] = deque()
        self.busy = False
        self.write_paused = False
        self.read_paused = False
        self.closing = False
        self.eof = False
        self.refusal: _Refusal | None = None
        self.last_active = time.monotonic()
        self.peer = ("", 0)

    # --- asyncio.Protocol ---------------------------------------------------------------
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        assert isinstance(transport, asyncio.Transport)
        self.transport = transport
        peer = transport.get_extra_info("peername")
        self.peer = (str(peer[0]), int(peer[1])) if isinstance(peer, tuple) else ("", 0)
        sock = transport.get_extra_info("socket")
        if sock is not None:
            try:
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            except OSError:
                pass
        if len(self.server.connections) >= self.server.max_connections:
            self._refuse(_Refusal("503 Service Unavailable", "ServiceUnavailable",
                                  f"more than {self.server.max_connections} connections are open; "
                                  "retry later"))
            return
        self.server.connections.add(self)

    def connection_lost(self, exc: Exception | None) -> None:
        self.closing = True
        self.server.connections.discard(self)

    def data_received(self, data: bytes) -> None:
        if self.closing:
            return
        self.last_active = time.monotonic()
        try:
            self.parser.feed_data(data)
        except httptools.HttpParserUpgrade:
            self.refusal = _Refusal("400 Bad Request", "BadRequest", "protocol upgrades are not supported")
        except httptools.HttpParserError as err:
            if self.refusal is None:
                self.refusal = _Refusal("400 Bad Request", "BadRequest",
                                        f"malformed HTTP request: {_parser_reason(err)}")
        if len(self.queue) >= MAX_PIPELINED and not self.read_paused:
            self.read_paused = True
            self.transport.pause_reading()  # type: ignore[union-attr]
        self._next()

    def eof_received(self) -> bool:
        """The client closed its sending side: answer what it sent, then close."""
        self.eof = True
        self._next()
        # keep the transport open for the answers (TLS has no half-close: asyncio closes it)
        return not self.server.tls

    def pause_writing(self) -> None:
        self.write_paused = True

    def resume_writing(self) -> None:
        self.write_paused = False
        self._next()

    # --- httptools callbacks ------------------------------------------------------------
    def on_message_begin(self) -> None:
        self.current = _Request()

    def on_url(self, url: bytes) -> None:
        req = self.current
        assert req is not None
        req.url += url
        req.header_bytes += len(url)
        if req.header_bytes > MAX_HEADER_BYTES and self.refusal is None:
            self.refusal = _Refusal("414 URI Too Long", "BadRequest",
                                    f"the request line is over {MAX_HEADER_BYTES} bytes")
            raise httptools.HttpParserError("too long")

    def on_header(self, name: bytes, value: bytes) -> None:
        req = self.current
        assert req is not None
        req.header_bytes += len(name) + len(value) + 4
        if req.header_bytes > MAX_HEADER_BYTES:
            if self.refusal is None:
                self.refusal = _Refusal("431 Request Header Fields Too Large", "BadRequest",
                                        f"the request's headers are over {MAX_HEADER_BYTES} bytes")
            raise httptools.HttpParserError("headers too large")
        req.headers.append((name, value))

    def on_headers_complete(self) -> None:
        req = self.current
        assert req is not None
        req.method = self.parser.get_method().decode("ascii", "replace")
        req.version = self.parser.get_http_version()
        req.keep_alive = self.parser.should_keep_alive()
        expect_continue = False
        for name, value in req.headers:
            lower = name.lower()
            if lower == b"content-length":
                if not value.strip().isdigit():
                    self.refusal = _Refusal("400 Bad Request", "BadRequest",
                                            f"Content-Length {value[:40]!r} is not a number of bytes")
                    raise httptools.HttpParserError("bad content-length")
                if int(value) > MAX_BODY_READ:
                    self.refusal = _too_large(f"{int(value)} bytes", self.server.max_body)
                    raise httptools.HttpParserError("body too large")
                req.too_large = int(value) > self.server.max_body
            elif lower == b"transfer-encoding" and b"chunked" in value.lower():
                req.chunked = True
            elif lower == b"expect" and value.strip().lower() == b"100-continue":
                expect_continue = True
        if expect_continue and req.version == "1.1" and self.transport is not None:
            self.transport.write(b"HTTP/1.1 100 Continue\r\n\r\n")

    def on_body(self, body: bytes) -> None:
        req = self.current
        assert req is not None
        req.body_size += len(body)
        if req.body_size > MAX_BODY_READ:
            if self.refusal is None:
                self.refusal = _too_large(f"over {MAX_BODY_READ} bytes", self.server.max_body)
            raise httptools.HttpParserError("body too large")
        if req.body_size > self.server.max_body:
            req.too_large = True
            req.body.clear()
        if not req.too_large:
            req.body.append(body)

    def on_message_complete(self) -> None:
        req = self.current
        assert req is not None
        self.current = None
        self.queue.append(req)

    # --- running requests in order ------------------------------------------------------
    def _next(self) -> None:
        while not self.busy and not self.closing and not self.write_paused:
            if not self.queue:
                if self.refusal is not None:
                    self._refuse(self.refusal)
                elif self.eof:
                    self.closing = True
                    self.transport.close()  # type: ignore[union-attr]
                elif self.read_paused:
                    self.read_paused = False
                    self.transport.resume_reading()  # type: ignore[union-attr]
                return
            req = self.queue.popleft()
            if req.too_large:  # read whole and thrown away: answer and close
                self._refuse(_too_large(f"{req.body_size} bytes", self.server.max_body))
                return
            environ = self.server.environ(req, self.peer)
            if self.server.inline(environ):
                self._answer(req, *self.server.call(environ))
                continue
            self.busy = True
            future = self.server.loop.run_in_executor(self.server.pool, self.server.call, environ)
            future.add_done_callback(lambda f, req=req: self._done(req, f))

    def _done(self, req: _Request, future: asyncio.Future[Any]) -> None:
        self.busy = False
        if self.closing:
            return
        self._answer(req, *future.result())
        self._next()

    def _answer(self, req: _Request, status: str, headers: list[tuple[str, str]], body: bytes) -> None:
        transport = self.transport
        assert transport is not None
        keep = req.keep_alive
        out = [f"HTTP/1.1 {status}\r\nServer: {SERVER_NAME}\r\nDate: {_date()}\r\n"]
        has_length = False
        for name, value in headers:
            lower = name.lower()
            if lower == "content-length":
                has_length = True
                continue
            if lower == "connection":
                if value.lower() == "close":
                    keep = False
                continue
            out.append(f"{name}: {value}\r\n")
        code = status[:3]
        bodyless = code in ("204", "304") or code.startswith("1")
        if not has_length and not bodyless and req.method != "HEAD":
            out.append(f"Content-Length: {len(body)}\r\n")
        elif has_length:
            out.append(next(f"Content-Length: {v}\r\n" for n, v in headers if n.lower() == "content-length"))
        if not keep:
            out.append("Connection: close\r\n")
        elif req.version == "1.0":
            out.append("Connection: Keep-Alive\r\n")
        out.append("\r\n")
        head = "".join(out).encode("latin-1")
        transport.write(head if bodyless or req.method == "HEAD" else head + body)
        if not keep:
            self.closing = True
            self.queue.clear()
            transport.close()

    def _refuse(self, refusal: _Refusal) -> None:
        self.closing = True
        self.queue.clear()
        if self.transport is not None:
            self.transport.write(_error_answer(refusal))
            self.transport.close()


def _too_large(size: str, limit: int) -> _Refusal:
    """Orion's answer to a body over the limit (the app words its own 413 the same way)."""
    return _Refusal("413 Request Entity Too Large", "RequestEntityTooLarge",
                    f"payload size: {size}, max size supported: {limit} bytes")


def _parser_reason(err: Exception) -> str:
    text = str(err).strip() or type(err).__name__
    return text[:200]


class HttpServer:
    """``run()`` serves until SIGTERM/SIGINT (or ``stop()`` from another thread); ``close()``
    releases the socket and the worker threads."""

    def __init__(self, app: WSGIApp, host: str, port: int, threads: int,
                 inline: Inline | None = None, *, max_connections: int = MAX_CONNECTIONS,
                 idle_timeout: float = IDLE_TIMEOUT, max_body: int = MAX_BODY,
                 ssl_context: ssl.SSLContext | None = None) -> None:
        self.app = app
        self.host, self.port = host, port
        self.inline: Inline = inline or (lambda _environ: False)
        self.max_connections = max_connections
        self.max_body = max_body
        self.tls = ssl_context is not None
        self.idle_timeout = idle_timeout
        self.pool = ThreadPoolExecutor(max_workers=max(1, threads), thread_name_prefix="cb-http")
        self.loop = asyncio.new_event_loop()
        self.connections: set[_Connection] = set()
        self._base = {"SERVER_NAME": host, "SERVER_PORT": str(port), "SCRIPT_NAME": "",
                      "SERVER_SOFTWARE": SERVER_NAME, "wsgi.version": (1, 0),
                      "wsgi.url_scheme": "http" if ssl_context is None else "https",
                      "wsgi.errors": sys.stderr,
                      "wsgi.multithread": True, "wsgi.multiprocess": False,
                      "wsgi.run_once": False, "wsgi.input_terminated": True}
        # bind now, so a port in use is an error of the constructor (OSError), not of run()
        try:
            self._server = self.loop.run_until_complete(self.loop.create_server(
                lambda: _Connection(self), host=host, port=port, reuse_address=True, backlog=1024,
                ssl=ssl_context, ssl_handshake_timeout=HANDSHAKE_TIMEOUT if ssl_context else None))
        except BaseException:
            self.loop.close()
            self.pool.shutdown(wait=False)
            raise

    # --- per request ---------------------------------------------------------------------
    def environ(self, req: _Request, peer: tuple[str, int]) -> dict[str, Any]:
        url = req.url
        path, _, query = url.partition(b"?")
        path, _, _fragment = path.partition(b"#")
        if path.startswith(b"http://") or path.startswith(b"https://"):  # absolute form
            path = b"/" + path.split(b"/", 3)[-1] if path.count(b"/") >= 3 else b"/"
        if path.startswith(b"//"):
            path = b"/" + path.lstrip(b"/")
        body = b"".join(req.body)
        environ = dict(self._base)
        environ.update({
            "REQUEST_METHOD": req.method,
            "PATH_INFO": unquote_to_bytes(path).decode("latin-1"),
            "QUERY_STRING": query.decode("latin-1"),
            "REQUEST_URI": url.decode("latin-1"),
            "SERVER_PROTOCOL": f"HTTP/{req.version}",
            "REMOTE_ADDR": peer[0], "REMOTE_HOST": peer[0], "REMOTE_PORT": str(peer[1]),
            "wsgi.input": io.BytesIO(body),
        })
        for name, value in req.headers:
            key = name.decode("latin-1").upper()
            if "_" in key:  # a header spelled with '_' could pose as one spelled with '-'
                continue
            key = key.replace("-", "_")
            text = value.decode("latin-1").strip()
            if key == "CONTENT_TYPE" or key == "CONTENT_LENGTH":
                environ[key] = text
                continue
            if key == "TRANSFER_ENCODING" and req.chunked:
                continue  # the body is de-chunked: the app sees its length instead
            key = "HTTP_" + key
            environ[key] = f"{environ[key]},{text}" if key in environ else text
        if req.chunked:
            environ["CONTENT_LENGTH"] = str(len(body))
        return environ

    def call(self, environ: dict[str, Any]) -> tuple[str, list[tuple[str, str]], bytes]:
        try:
            return run_wsgi(self.app, environ)
        except Exception as err:  # the app answers its own errors; this is a bug below it
            log.exception("unexpected error serving %s %s", environ.get("REQUEST_METHOD"),
                          environ.get("PATH_INFO"))
            body = json.dumps({"error": "InternalServerError",
                               "description": f"internal error ({type(err).__name__}); see the "
                                              "context broker's log"}).encode()
            return "500 Internal Server Error", [("Content-Type", "application/json")], body

    # --- lifecycle -----------------------------------------------------------------------
    def _sweep(self) -> None:
        """Close connections idle for ``idle_timeout`` s (keep-alive or stalled mid-request)."""
        now = time.monotonic()
        for conn in list(self.connections):
            if not conn.busy and now - conn.last_active > self.idle_timeout and conn.transport:
                conn.closing = True
                conn.transport.close()
        self.loop.call_later(min(10.0, self.idle_timeout / 2), self._sweep)

    def run(self, stop_signals: tuple[signal.Signals, ...] = (signal.SIGTERM, signal.SIGINT)) -> str:
        """Serve until one of ``stop_signals`` (its name is returned) or :meth:`stop`."""
        got: list[str] = []
        for sig in stop_signals:
            self.loop.add_signal_handler(sig, lambda s=sig: (got.append(s.name), self.loop.stop()))
        self.loop.call_later(min(10.0, self.idle_timeout / 2), self._sweep)
        try:
            self.loop.run_forever()
        finally:
            for sig in stop_signals:
                self.loop.remove_signal_handler(sig)
        return got[0] if got else "stop"

    def stop(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)

    def close(self) -> None:
        self._server.close()
        for conn in list(self.connections):
            if conn.transport is not None:
                conn.transport.close()
        self.loop.run_until_complete(self._server.wait_closed())
        self.pool.shutdown(wait=True, cancel_futures=True)
        self.loop.run_until_complete(asyncio.sleep(0))
        self.loop.close()


def make_server(app: WSGIApp, host: str, port: int, threads: int,
                inline: Inline | None = None, max_body: int = MAX_BODY,
                ssl_context: ssl.SSLContext | None = None) -> HttpServer:
    """The server for ``app`` on ``host:port`` (bound on return; ``run()`` serves), HTTPS only
    with ``ssl_context``."""
    return HttpServer(app, host, port, threads, inline, max_body=max_body, ssl_context=ssl_context)
