"""The real context broker process on loopback, for its benchmark and its outside-in tests.

- :class:`ContextBroker`: ``python -m engine.context_broker`` on a free port, a data folder and a
  token file of its own; :meth:`ContextBroker.start` polls until it answers HTTP, :meth:`stop`
  leaves no process behind, :meth:`log_text` is what it wrote (tests look for tracebacks there).
- :class:`Http`: one keep-alive ``http.client`` connection that sends exactly the bytes and headers
  it is given (bad JSON, a wrong ``Content-Type``, any method) and reads the answer as
  :class:`Reply`; it reconnects once when the server closed an idle connection.
- :func:`raw_request`: a request written on a bare socket, for what ``http.client`` will not send
  (a body without ``Content-Length``).

Kept apart from the benchmark so the tests (tests/integration/test_context_broker_*.py) start the
broker exactly as the benchmark does.
"""

from __future__ import annotations

import http.client
import json
import secrets
import socket
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from engine import netutil, parts, process

READY_DEADLINE = 30.0
OPENAPI_PATH = "/plantkg/v1/openapi.json"


@dataclass(frozen=True)
class Reply:
    """One HTTP answer: status, headers (names lower-cased) and raw body."""

    status: int
    headers: Mapping[str, str]
    body: bytes

    def json(self) -> Any:
        return json.loads(self.body) if self.body else None

    def header(self, name: str) -> str | None:
        return self.headers.get(name.lower())


class Http:
    """A keep-alive HTTP/1.1 connection to ``host:port`` (not thread-safe: one per thread)."""

    def __init__(self, host: str, port: int, timeout: float = 30.0) -> None:
        self.host, self.port, self.timeout = host, port, timeout
        self.conn = http.client.HTTPConnection(host, port, timeout=timeout)

    def request(self, method: str, path: str, body: bytes | str | None = None,
                headers: Mapping[str, str] | None = None) -> Reply:
        data = body.encode("utf-8") if isinstance(body, str) else body
        for attempt in (1, 2):
            try:
                self.conn.request(method, path, body=data, headers=dict(headers or {}))
                resp = self.conn.getresponse()
                payload = resp.read()
                reply = Reply(resp.status, {k.lower(): v for k, v in resp.getheaders()}, payload)
                if resp.will_close:
                    self.reconnect()
                return reply
            except (http.client.RemoteDisconnected, BrokenPipeError, ConnectionResetError):
                self.reconnect()
                if attempt == 2:
                    raise
        raise AssertionError("unreachable")

    def reconnect(self) -> None:
        self.conn.close()
        self.conn = http.client.HTTPConnection(self.host, self.port, timeout=self.timeout)

    def close(self) -> None:
        self.conn.close()


def raw_request(host: str, port: int, head: str, body: bytes = b"", timeout: float = 10.0) -> Reply:
    """Write ``head`` (request line and headers, without the blank line) and ``body`` on a fresh
    socket exactly as given, half-close it, and parse the answer (``Connection: close`` is added)."""
    with socket.create_connection((host, port), timeout=timeout) as sock:
        sock.sendall(head.rstrip("\r\n").encode("latin-1") + b"\r\nConnection: close\r\n\r\n" + body)
        sock.shutdown(socket.SHUT_WR)
        chunks = []
        while chunk := sock.recv(65536):
            chunks.append(chunk)
    return parse_response(b"".join(chunks))


def parse_response(data: bytes) -> Reply:
    """An HTTP/1.x response read to the end of the connection (chunked bodies decoded)."""
    head, _, body = data.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    if not lines or not lines[0].startswith("HTTP/"):
        raise ValueError(f"not an HTTP response: {data[:200]!r}")
    status = int(lines[0].split()[1])
    headers = {}
    for line in lines[1:]:
        name, _, value = line.partition(":")
        headers[name.strip().lower()] = value.strip()
    if headers.get("transfer-encoding", "").lower() == "chunked":
        body = _dechunk(body)
    elif "content-length" in headers:
        body = body[:int(headers["content-length"])]
    return Reply(status, headers, body)


def _dechunk(data: bytes) -> bytes:
    out, rest = [], data
    while rest:
        size_line, _, rest = rest.partition(b"\r\n")
        size = int(size_line.split(b";")[0] or b"0", 16)
        if size == 0:
            break
        out.append(rest[:size])
        rest = rest[size + 2:]
    return b"".join(out)


@dataclass
class ContextBroker:
    """``python -m engine.context_broker`` with its data in ``folder`` (``data/``, ``token``,
    ``context-broker.log``). ``open_writes`` runs it with ``--open`` (no token checked)."""

    folder: Path
    host: str = "127.0.0.1"
    port: int = 0
    open_writes: bool = False
    extra_args: tuple[str, ...] = ()
    token: str = field(default_factory=lambda: secrets.token_urlsafe(32))
    child: process.Child | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        self.port = self.port or netutil.free_port(self.host)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.token_file.write_text(self.token + "\n", encoding="utf-8")
        self.token_file.chmod(0o600)

    @property
    def token_file(self) -> Path:
        return self.folder / "token"

    @property
    def data_dir(self) -> Path:
        return self.folder / "data"

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}"

    @property
    def auth(self) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.token}"}

    def argv(self) -> list[str]:
        access = ["--open"] if self.open_writes else ["--token-file", str(self.token_file)]
        return [sys.executable, "-m", "engine.context_broker", "--host", self.host, "--port",
                str(self.port), "--data-dir", str(self.data_dir), *access, *self.extra_args]

    def start(self, deadline: float = READY_DEADLINE) -> ContextBroker:
        self.child = process.spawn(self.argv(), log_dir=self.folder, name="context-broker",
                                   cwd=parts.repo_root())
        try:
            process.wait_until(self._answers, deadline, 0.05, what=f"the context broker on {self.url}",
                               child=self.child)
        except BaseException:
            self.stop()
            raise
        return self

    def _answers(self) -> bool:
        try:
            conn = http.client.HTTPConnection(self.host, self.port, timeout=2)
            try:
                conn.request("GET", "/version")
                return conn.getresponse().status == 200
            finally:
                conn.close()
        except OSError:
            return False

    def http(self) -> Http:
        return Http(self.host, self.port)

    def stop(self) -> None:
        if self.child is not None:
            process.stop(self.child)
            self.child = None

    def log_text(self) -> str:
        path = self.folder / "context-broker.log"
        return path.read_text(encoding="utf-8", errors="replace") if path.is_file() else ""

    def __enter__(self) -> ContextBroker:
        return self.start() if self.child is None else self

    def __exit__(self, *exc: object) -> None:
        self.stop()
