"""HTTP/1.1 keep-alive for the agent's server: one connection carries many requests.

werkzeug's development server closes every connection after one answer (its handler adds
``Connection: close`` and then discards whatever the client sent meanwhile — with keep-alive that
could be the next request). An engine talking to an agent on loopback paid a TCP handshake per
call, most of a call's cost. :class:`KeepAliveHandler` runs the WSGI app itself instead:

- the request body is read through a bounded reader that counts what the app consumed; after the
  answer the rest of the body is read and dropped, exactly ``Content-Length`` bytes, never more,
  so the next request on the connection is intact;
- the answer is buffered whole (the agent's answers are small JSON documents) and sent with its
  ``Content-Length``;
- the connection is kept only when that is safe: an HTTP/1.1 request without ``Connection:
  close``, without a chunked body, with a body of at most ``MAX_DRAIN`` bytes (the agent refuses
  more with 413 anyway); anything else is answered with ``Connection: close``, as before;
- an idle connection is closed after ``IDLE_TIMEOUT`` s (a client reconnects; AgentClient retries
  a request once when a kept connection turns out closed), and :func:`close_connections` closes
  every open one when the agent stops, so no thread answers for a stopped agent.

TLS (``ssl_context`` of werkzeug's server) is below this handler and unaffected.
"""

from __future__ import annotations

import socket
import threading
from collections.abc import Iterable
from typing import Any

from werkzeug.serving import BaseWSGIServer, WSGIRequestHandler

#: Bodies up to this size are drained after the answer, so the connection can be kept.
MAX_DRAIN = 16 << 20
#: Seconds an idle kept connection waits for its next request.
IDLE_TIMEOUT = 60.0
_OPEN = "plantkg_open_connections"


class _Body:
    """``wsgi.input`` limited to the request's ``Content-Length``; counts what was read."""

    def __init__(self, raw: Any, length: int) -> None:
        self._raw = raw
        self.left = length

    def read(self, size: int = -1) -> bytes:
        return self._take(self._raw.read, size)

    def readline(self, size: int = -1) -> bytes:
        return self._take(self._raw.readline, size)

    def _take(self, reader: Any, size: int | None) -> bytes:
        if self.left <= 0:
            return b""
        data = reader(self.left if size is None or size < 0 else min(size, self.left))
        self.left -= len(data)
        return data

    def __iter__(self) -> Iterable[bytes]:
        while line := self.readline():
            yield line

    def drain(self) -> bool:
        """Read and drop the unread rest of the body; False if the client sent less."""
        while self.left > 0:
            if not self.read(min(self.left, 65536)):
                return False
        return True


class KeepAliveHandler(WSGIRequestHandler):
    """werkzeug's request handler, answering on a connection it keeps open (see the module)."""

    timeout = IDLE_TIMEOUT

    def setup(self) -> None:
        super().setup()
        # Headers and body go out in two writes; without this, Nagle's algorithm holds the body
        # back until the client's delayed ACK (40 ms) on a kept connection.
        try:
            self.connection.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        except OSError:
            pass
        with _lock:
            getattr(self.server, _OPEN, set()).add(self.connection)

    def finish(self) -> None:
        with _lock:
            getattr(self.server, _OPEN, set()).discard(self.connection)
        super().finish()

    def run_wsgi(self) -> None:
        environ = self.environ = self.make_environ()
        length_text = environ.get("CONTENT_LENGTH") or "0"
        length = int(length_text) if length_text.isdigit() else -1
        chunked = "wsgi.input_terminated" in environ  # werkzeug saw Transfer-Encoding: chunked
        keep = (not self.close_connection and self.request_version == "HTTP/1.1" and not chunked
                and 0 <= length <= MAX_DRAIN)
        body = None
        if keep:
            body = _Body(self.rfile, length)
            environ["wsgi.input"] = body
        try:
            status, headers, payload = self._call_app(environ)
        except Exception as exc:  # noqa: BLE001 - the app's own handlers answer every error
            self.server.log("error", f"Error on request {self.command} {self.path}: {exc!r}")
            status, headers, payload = "500 INTERNAL SERVER ERROR", [
                ("Content-Type", "text/plain; charset=utf-8")], b"internal error\n"
            keep = False
        if body is not None and not body.drain():
            keep = False
        self.close_connection = not keep
        code, _, reason = status.partition(" ")
        try:
            self.send_response(int(code), reason)
            for name, value in headers:
                if name.lower() not in ("content-length", "connection", "transfer-encoding"):
                    self.send_header(name, value)
            if int(code) not in (204, 304) and not 100 <= int(code) < 200:
                self.send_header("Content-Length", str(len(payload)))
            if not keep:
                self.send_header("Connection", "close")
            self.end_headers()
            if payload and self.command != "HEAD":
                self.wfile.write(payload)
        except (ConnectionError, socket.timeout) as exc:
            self.close_connection = True
            self.connection_dropped(exc, environ)

    def _call_app(self, environ: dict[str, Any]) -> tuple[str, list[tuple[str, str]], bytes]:
        """Run the app; its status, headers and whole body."""
        started: list[Any] = []

        def start_response(status: str, headers: list[tuple[str, str]], exc_info: Any = None) -> Any:
            if exc_info and started:
                raise exc_info[1].with_traceback(exc_info[2])
            started[:] = [status, headers]
            return lambda data: chunks.append(data)

        chunks: list[bytes] = []
        result = self.server.app(environ, start_response)
        try:
            for data in result:
                chunks.append(data)
        finally:
            close = getattr(result, "close", None)
            if close is not None:
                close()
        if not started:
            raise RuntimeError("the WSGI app answered without start_response")
        return started[0], started[1], b"".join(chunks)


_lock = threading.Lock()


def keep_alive(server: BaseWSGIServer) -> BaseWSGIServer:
    """Prepare ``server`` (built with :class:`KeepAliveHandler`) to track its connections."""
    setattr(server, _OPEN, set())
    return server


def close_connections(server: BaseWSGIServer) -> None:
    """Shut every open connection of ``server`` down (after ``server.shutdown()``): their
    threads, waiting for a next request, see the end of the stream and finish."""
    with _lock:
        open_now = list(getattr(server, _OPEN, ()))
    for conn in open_now:
        try:
            conn.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass


__all__ = ["KeepAliveHandler", "close_connections", "keep_alive", "MAX_DRAIN", "IDLE_TIMEOUT"]
