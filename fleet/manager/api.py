"""The fleet manager's HTTP API, on loopback, with the agents' token scheme.

``Authorization: Bearer <token>`` on every request (compared in constant time); the token is
``<data-dir>/manager.token`` (created 0600 at the first start), the address is in
``<data-dir>/manager.json`` (``{"url", "pid"}``), which is how ``plantkg fleet order`` finds a
running manager. Errors are JSON ``{"error", "description"}`` with a 4xx status naming the field:

| method | path | what |
|--------|------|------|
| GET | ``/v1/vehicles`` | every vehicle: record, connection state, last state |
| GET | ``/v1/vehicles/<serial>`` | one vehicle (404 if unknown) |
| POST | ``/v1/orders`` | ``{"serial", "manufacturer"?, "orderId"?, "nodes": [{"nodeId", "x", "y", "mapId", "actions": [..]}]}`` → 201 ``{"orderId", "topic"}``; 409 if the vehicle is not ONLINE |
| POST | ``/v1/instantActions`` | ``{"serial", "manufacturer"?, "actionType", "actionParameters"?}`` → 201 ``{"actionId", "actionType", "vehicle", "topic"}``; ``actionType`` a VDA 5050 2.1 instant action (fleet/manager/instant.py); 409 if the vehicle is not ONLINE |
| POST | ``/v1/reconcile`` | reconcile now → 202 |

Until the manager has read its vehicle records after a (re)start, the vehicle resources answer
503 ``{"error": "NotReady", ...}``: a client waits and asks again (an empty list would read as
"every vehicle is gone").

A request body is at most 1 MB; a slow client holds one thread of its own, not the manager.
"""

from __future__ import annotations

import hmac
import json
import logging
import secrets
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any, Protocol

from fleet.discovery import files

log = logging.getLogger("fleet.manager")
MAX_BODY = 1_000_000


class ApiError(Exception):
    def __init__(self, status: int, error: str, description: str) -> None:
        super().__init__(description)
        self.status, self.error, self.description = status, error, description


class Manager(Protocol):
    def vehicles(self) -> list[dict[str, Any]]: ...
    def send_order(self, body: Any) -> dict[str, Any]: ...
    def send_instant_action(self, body: Any) -> dict[str, Any]: ...
    def request_reconcile(self) -> None: ...


def token_for(data_dir: Path) -> str:
    """The manager's token, created (0600) if there is none."""
    path = data_dir / "manager.token"
    if not path.exists():
        data_dir.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(".manager.token.tmp")
        tmp.write_text(secrets.token_urlsafe(32), encoding="utf-8")
        tmp.chmod(0o600)
        tmp.replace(path)
    return path.read_text(encoding="utf-8").strip()


def _handler(manager: Manager, token: str) -> type[BaseHTTPRequestHandler]:
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

        def _authorized(self) -> bool:
            scheme, _, given = (self.headers.get("Authorization") or "").partition(" ")
            if scheme.lower() == "bearer" and hmac.compare_digest(given.strip().encode("utf-8"), expected):
                return True
            self._send(401, {"error": "Unauthorized",
                             "description": "send 'Authorization: Bearer <token>' with the token "
                                            "from <data-dir>/manager.token"})
            return False

        def _body(self) -> Any:
            try:
                length = int(self.headers.get("Content-Length") or 0)
            except ValueError:
                raise ApiError(400, "BadRequest", "Content-Length is not a number") from None
            if length > MAX_BODY:
                raise ApiError(413, "PayloadTooLarge", f"body of {length} bytes, at most {MAX_BODY}")
            try:
                return json.loads(self.rfile.read(length) or b"null")
            except (UnicodeDecodeError, ValueError) as exc:
                raise ApiError(400, "ParseError", f"the body is not JSON: {exc}") from None

        def _route(self, method: str) -> None:
            if not self._authorized():
                return
            path = self.path.split("?", 1)[0].rstrip("/")
            try:
                if method == "GET" and path == "/v1/vehicles":
                    self._send(200, manager.vehicles())
                elif method == "GET" and path.startswith("/v1/vehicles/"):
                    name = path[len("/v1/vehicles/"):]
                    found = [v for v in manager.vehicles() if name in (v["serial"], v["vehicle"])]
                    if not found:
                        raise ApiError(404, "NotFound", f"no vehicle {name!r}")
                    self._send(200, found[0])
                elif method == "POST" and path == "/v1/orders":
                    self._send(201, manager.send_order(self._body()))
                elif method == "POST" and path == "/v1/instantActions":
                    self._send(201, manager.send_instant_action(self._body()))
                elif method == "POST" and path == "/v1/reconcile":
                    manager.request_reconcile()
                    self._send(202, {"reconcile": "requested"})
                else:
                    raise ApiError(404 if method == "GET" else 405, "NotFound",
                                   f"{method} {path}: no such resource (see fleet/manager/api.py)")
            except ApiError as exc:
                self._send(exc.status, {"error": exc.error, "description": exc.description})
            except Exception as exc:  # a bug answers 500 with its name, the server goes on
                log.exception("API %s %s failed", method, path)
                self._send(500, {"error": "InternalError", "description": f"{type(exc).__name__}: {exc}"})

        def do_GET(self) -> None:  # noqa: N802 - http.server's name
            self._route("GET")

        def do_POST(self) -> None:  # noqa: N802
            self._route("POST")

    return Handler


class ApiServer:
    def __init__(self, manager: Manager, data_dir: Path, host: str = "127.0.0.1", port: int = 0) -> None:
        self.data_dir = data_dir
        self.server = ThreadingHTTPServer((host, port), _handler(manager, token_for(data_dir)))
        self.server.daemon_threads = True
        self.thread = threading.Thread(target=self.server.serve_forever, name="fleet-api", daemon=True)

    @property
    def url(self) -> str:
        host, port = self.server.server_address[:2]
        return f"http://{host}:{port}"

    def start(self, pid: int) -> None:
        self.thread.start()
        files.atomic_write(self.data_dir / "manager.json", json.dumps({"url": self.url, "pid": pid}) + "\n")

    def stop(self) -> None:
        self.server.shutdown()
        self.server.server_close()
        (self.data_dir / "manager.json").unlink(missing_ok=True)
