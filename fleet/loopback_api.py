"""A small JSON API on loopback with a bearer token: what the fleet manager and the task planner
each serve to their clients (``plantkg fleet ...``, the planner, the HMI, tests).

One copy of the plumbing: the token file (``<data-dir>/<name>.token``, made 0600 at the first
start, compared in constant time), the address file (``<data-dir>/<name>.json``: ``{"url",
"pid"}``, which is how clients find a server started on a free port), JSON bodies bounded in size,
errors as ``{"error", "description"}`` with a 4xx status, and a 500 naming the exception for a bug
(the server goes on). Each request is served by a thread of its own with a 10 s socket timeout, so
a client that stalls mid-request holds only its own thread. What a path does is the caller's
``route``.
"""

from __future__ import annotations

import hmac
import json
import logging
import secrets
import threading
from collections.abc import Callable
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from fleet.discovery import files

log = logging.getLogger("fleet.api")

#: ``route(method, path, body)`` -> (status, JSON answer); ``body()`` reads the request's JSON.
Route = Callable[[str, str, Callable[[], Any]], tuple[int, Any]]


class ApiError(Exception):
    """A refusal: the status, a short error name and a description naming the field."""

    def __init__(self, status: int, error: str, description: str) -> None:
        super().__init__(description)
        self.status, self.error, self.description = status, error, description


def token_for(data_dir: Path, name: str) -> str:
    """The token of ``<data_dir>/<name>.token``, created (0600, random) if there is none."""
    path = data_dir / f"{name}.token"
    if not path.exists():
        data_dir.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{name}.token.tmp")
        tmp.write_text(secrets.token_urlsafe(32), encoding="utf-8")
        tmp.chmod(0o600)
        tmp.replace(path)
    return path.read_text(encoding="utf-8").strip()


def _handler(route: Route, token: str, name: str, max_body: int) -> type[BaseHTTPRequestHandler]:
    expected = token.encode("utf-8")

    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"
        timeout = 10  # a client that stalls mid-request loses its connection, nobody else waits

        def log_message(self, *_: object) -> None:
            pass

        def _send(self, status: int, body: Any) -> None:
            data = json.dumps(body).encode("utf-8")
            self.send_response(status)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

        def _body(self) -> Any:
            try:
                length = int(self.headers.get("Content-Length") or 0)
            except ValueError:
                raise ApiError(400, "BadRequest", "Content-Length is not a number") from None
            if length > max_body:
                raise ApiError(413, "PayloadTooLarge", f"body of {length} bytes, at most {max_body}")
            try:
                return json.loads(self.rfile.read(length) or b"null")
            except (UnicodeDecodeError, ValueError) as exc:
                raise ApiError(400, "ParseError", f"the body is not JSON: {exc}") from None

        def _serve(self, method: str) -> None:
            scheme, _, given = (self.headers.get("Authorization") or "").partition(" ")
            if not (scheme.lower() == "bearer" and hmac.compare_digest(given.strip().encode("utf-8"), expected)):
                self._send(401, {"error": "Unauthorized", "description": "send 'Authorization: Bearer <token>' "
                                 f"with the token from <data-dir>/{name}.token"})
                return
            path = self.path.split("?", 1)[0].rstrip("/")
            try:
                self._send(*route(method, path, self._body))
            except ApiError as exc:
                self._send(exc.status, {"error": exc.error, "description": exc.description})
            except Exception as exc:  # a bug answers 500 with its name, the server goes on
                log.exception("%s API %s %s failed", name, method, path)
                self._send(500, {"error": "InternalError", "description": f"{type(exc).__name__}: {exc}"})

        def do_GET(self) -> None:  # noqa: N802 - http.server's name
            self._serve("GET")

        def do_POST(self) -> None:  # noqa: N802
            self._serve("POST")

    return Handler


class LoopbackServer:
    """Serve ``route`` on ``host:port`` (0: a free port) in a thread; ``start`` writes the address file."""

    def __init__(self, route: Route, data_dir: Path, name: str, host: str = "127.0.0.1", port: int = 0,
                 max_body: int = 1_000_000) -> None:
        self.data_dir, self.name = data_dir, name
        self.server = ThreadingHTTPServer((host, port), _handler(route, token_for(data_dir, name), name, max_body))
        self.server.daemon_threads = True
        self.thread = threading.Thread(target=self.server.serve_forever, name=f"{name}-api", daemon=True)

    @property
    def url(self) -> str:
        host, port = self.server.server_address[:2]
        return f"http://{host}:{port}"

    def start(self, pid: int) -> None:
        self.thread.start()
        files.atomic_write(self.data_dir / f"{self.name}.json", json.dumps({"url": self.url, "pid": pid}) + "\n")

    def stop(self) -> None:
        self.server.shutdown()
        self.server.server_close()
        (self.data_dir / f"{self.name}.json").unlink(missing_ok=True)
