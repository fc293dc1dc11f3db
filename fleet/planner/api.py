"""The planner's HTTP API, on loopback, with a bearer token (the fleet manager's scheme).

The token is ``<data-dir>/planner.token`` (created 0600 at the first start), the address is in
``<data-dir>/planner.json`` (``{"url", "pid"}``). Errors are JSON ``{"error", "description"}``
with a 4xx status naming the field; a bug answers 500 with its name and the planner goes on.

| method | path | what |
|--------|------|------|
| GET | ``/v1/tasks`` | ``{"tasks": [...], "jobs": {...}, "events": N}`` |
| GET | ``/v1/tasks/<id>`` | one task (404 if unknown) |
| POST | ``/v1/jobs`` | ``{"tasks": [LoTLan task names]?}`` (default: the program's start tasks) -> 201 ``{"job", "tasks"}`` |
| POST | ``/v1/events`` | ``{"event": name or physical name, "value": true}`` -> 201 the journaled event |
| POST | ``/v1/tasks/<id>/withdraw`` | -> 200 the task, 409 if it is final already |
"""

from __future__ import annotations

import hmac
import json
import logging
import secrets
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from fleet.discovery import files
from fleet.planner.service import Planner, RequestError

log = logging.getLogger("fleet.planner")
MAX_BODY = 100_000


def token_for(data_dir: Path) -> str:
    path = data_dir / "planner.token"
    if not path.exists():
        data_dir.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(".planner.token.tmp")
        tmp.write_text(secrets.token_urlsafe(32), encoding="utf-8")
        tmp.chmod(0o600)
        tmp.replace(path)
    return path.read_text(encoding="utf-8").strip()


def _handler(planner: Planner, token: str) -> type[BaseHTTPRequestHandler]:
    expected = token.encode("utf-8")

    class Handler(BaseHTTPRequestHandler):
        protocol_version = "HTTP/1.1"
        timeout = 10

        def log_message(self, *_: object) -> None:
            pass

        def _send(self, status: int, body: Any) -> None:
            data = json.dumps(body).encode("utf-8")
            self.send_response(status)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(data)))
            self.end_headers()
            self.wfile.write(data)

        def _body(self) -> dict[str, Any]:
            try:
                length = int(self.headers.get("Content-Length") or 0)
            except ValueError:
                raise RequestError(400, "Content-Length is not a number") from None
            if length > MAX_BODY:
                raise RequestError(413, f"body of {length} bytes, at most {MAX_BODY}")
            try:
                body = json.loads(self.rfile.read(length) or b"{}")
            except (UnicodeDecodeError, ValueError) as exc:
                raise RequestError(400, f"the body is not JSON: {exc}") from None
            if not isinstance(body, dict):
                raise RequestError(400, f"the body must be a JSON object, got {type(body).__name__}")
            return body

        def _route(self, method: str) -> None:
            scheme, _, given = (self.headers.get("Authorization") or "").partition(" ")
            if not (scheme.lower() == "bearer" and hmac.compare_digest(given.strip().encode("utf-8"), expected)):
                self._send(401, {"error": "Unauthorized", "description": "send 'Authorization: Bearer <token>' "
                                 "with the token from <data-dir>/planner.token"})
                return
            path = self.path.split("?", 1)[0].rstrip("/")
            parts = path.split("/")
            try:
                if method == "GET" and path == "/v1/tasks":
                    self._send(200, planner.snapshot())
                elif method == "GET" and len(parts) == 4 and parts[:3] == ["", "v1", "tasks"]:
                    self._send(200, planner.task_json(parts[3]))
                elif method == "POST" and path == "/v1/jobs":
                    names = self._body().get("tasks")
                    if names is not None and (not isinstance(names, list) or not all(isinstance(n, str) for n in names)):
                        raise RequestError(400, f"tasks: expected a list of LoTLan task names, got {names!r}"[:300])
                    self._send(201, planner.start_job(names))
                elif method == "POST" and path == "/v1/events":
                    body = self._body()
                    if "value" not in body:
                        raise RequestError(400, "value: missing (e.g. {\"event\": \"loaded\", \"value\": true})")
                    self._send(201, planner.fire(body.get("event"), body["value"]))
                elif method == "POST" and len(parts) == 5 and parts[:3] == ["", "v1", "tasks"] and parts[4] == "withdraw":
                    self._send(200, planner.withdraw(parts[3]))
                else:
                    raise RequestError(404 if method == "GET" else 405,
                                       f"{method} {path}: no such resource (see fleet/planner/api.py)")
            except RequestError as exc:
                self._send(exc.status, {"error": {400: "BadRequest", 404: "NotFound", 405: "MethodNotAllowed",
                                                  409: "Conflict", 413: "PayloadTooLarge"}.get(exc.status, "Error"),
                                        "description": exc.message})
            except Exception as exc:  # a bug: 500 with its name, the planner goes on
                log.exception("API %s %s failed", method, path)
                self._send(500, {"error": "InternalError", "description": f"{type(exc).__name__}: {exc}"})

        def do_GET(self) -> None:  # noqa: N802
            self._route("GET")

        def do_POST(self) -> None:  # noqa: N802
            self._route("POST")

    return Handler


class ApiServer:
    def __init__(self, planner: Planner, data_dir: Path, host: str = "127.0.0.1", port: int = 0) -> None:
        self.data_dir = data_dir
        self.server = ThreadingHTTPServer((host, port), _handler(planner, token_for(data_dir)))
        self.server.daemon_threads = True
        self.thread = threading.Thread(target=self.server.serve_forever, name="planner-api", daemon=True)

    @property
    def url(self) -> str:
        host, port = self.server.server_address[:2]
        return f"http://{host}:{port}"

    def start(self, pid: int) -> None:
        self.thread.start()
        files.atomic_write(self.data_dir / "planner.json", json.dumps({"url": self.url, "pid": pid}) + "\n")

    def stop(self) -> None:
        self.server.shutdown()
        self.server.server_close()
        (self.data_dir / "planner.json").unlink(missing_ok=True)
