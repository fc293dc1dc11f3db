"""The NGSI worker's HTTP client against a small real HTTP server of the test: which answers are
retried, which are refused, the token sent and re-read, keep-alive, and the readiness rule."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from engine import netutil
from engine.bridge_worker.ngsi_client import NgsiClient, NgsiRefused, NgsiUnavailable
from engine.bridge_worker.ngsi_health import NgsiHealth


class Server:
    """Answers every request with the next scripted (status, body); records what it got."""

    def __init__(self) -> None:
        self.script: list[tuple[int, object]] = []
        self.got: list[tuple[str, str, str | None, int]] = []  # method, path, auth, connection no.
        self.connections = 0
        server = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def setup(self) -> None:
                super().setup()
                server.connections += 1
                self.number = server.connections

            def _answer(self) -> None:
                self.rfile.read(int(self.headers.get("Content-Length") or 0))
                server.got.append((self.command, self.path, self.headers.get("Authorization"), self.number))
                status, body = server.script.pop(0) if server.script else (204, None)
                raw = json.dumps(body).encode() if body is not None else b""
                self.send_response(status)
                self.send_header("Content-Length", str(len(raw)))
                self.end_headers()
                self.wfile.write(raw)

            do_GET = do_POST = do_DELETE = _answer  # noqa: N815 - http.server's names

            def log_message(self, *_: object) -> None:
                pass

        self.port = netutil.free_port("127.0.0.1")
        self.httpd = ThreadingHTTPServer(("127.0.0.1", self.port), Handler)
        threading.Thread(target=self.httpd.serve_forever, args=(0.02,), daemon=True).start()

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"


@pytest.fixture
def server() -> Iterator[Server]:
    srv = Server()
    yield srv
    srv.httpd.shutdown()
    srv.httpd.server_close()


ENTITY = {"id": "e", "type": "T", "x": {"type": "Number", "value": 1}}


@pytest.mark.parametrize("status", [500, 503, 429, 401, 403])
def test_answers_that_are_retried(server: Server, status: int) -> None:
    server.script = [(status, {"error": "X", "description": "why"})]
    with pytest.raises(NgsiUnavailable) as exc:
        NgsiClient(server.url).upsert(ENTITY)
    assert exc.value.status == status and f"-> {status} X: why" in exc.value.text


@pytest.mark.parametrize("status", [400, 404, 413, 422])
def test_answers_that_refuse_the_content(server: Server, status: int) -> None:
    server.script = [(status, {"error": "BadRequest", "description": "Invalid characters in attribute value"})]
    with pytest.raises(NgsiRefused) as exc:
        NgsiClient(server.url).upsert(ENTITY)
    assert exc.value.status == status and "Invalid characters in attribute value" in exc.value.text


def test_no_context_broker_is_retried() -> None:
    with pytest.raises(NgsiUnavailable):
        NgsiClient(f"http://127.0.0.1:{netutil.free_port('127.0.0.1')}", timeout=2).version()


def test_token_is_sent_never_shown_and_read_again_after_a_401(server: Server, tmp_path: Path) -> None:
    token = tmp_path / "remote.token"
    token.write_text("old-token-7c1\n")
    client = NgsiClient(server.url, token)
    server.script = [(401, {"error": "Unauthorized", "description": "wrong token"})]
    with pytest.raises(NgsiUnavailable) as exc:
        client.upsert(ENTITY)
    assert "old-token-7c1" not in exc.value.text and "token" in exc.value.text
    token.write_text("new-token-9d2\n")
    with pytest.raises(NgsiUnavailable):  # read again only after a 401: this one still went old
        server.script = [(401, {"error": "Unauthorized", "description": "wrong token"})]
        client.upsert(ENTITY)
    client.upsert(ENTITY)
    assert [auth for _, _, auth, _ in server.got] == ["Bearer old-token-7c1", "Bearer old-token-7c1",
                                                     "Bearer new-token-9d2"]
    assert NgsiClient(server.url).version().status == 204
    assert server.got[-1][2] is None  # no token file: no header (an open context broker)


def test_one_connection_is_kept_alive(server: Server) -> None:
    client = NgsiClient(server.url)
    for _ in range(5):
        client.upsert(ENTITY)
    assert {n for *_, n in server.got} == {1}
    assert [(m, p) for m, p, *_ in server.got][0] == ("POST", "/v2/entities?options=upsert")


def test_subscriptions_are_read_page_by_page(server: Server) -> None:
    server.script = [(200, [{"id": str(i)} for i in range(1000)]), (200, [{"id": "1000"}])]
    server_headers_total = 1001

    class Counted(NgsiClient):
        def _answer(self, what, response, raw):  # type: ignore[no-untyped-def]
            answer = super()._answer(what, response, raw)
            answer.headers["fiware-total-count"] = str(server_headers_total)
            return answer

    found = Counted(server.url).list_subscriptions()
    assert len(found) == 1001
    assert [p for _, p, *_ in server.got] == ["/v2/subscriptions?options=count&limit=1000&offset=0",
                                             "/v2/subscriptions?options=count&limit=1000&offset=1000"]


def test_deleting_a_subscription_that_is_gone_is_fine(server: Server) -> None:
    server.script = [(404, {"error": "NotFound", "description": "gone"}), (400, {"error": "BadRequest"})]
    client = NgsiClient(server.url)
    client.delete_subscription("s1")
    with pytest.raises(NgsiRefused):
        client.delete_subscription("s2")


READY = [
    # mqtt, ngsi, subscribed, subscriptions made, token refused, stopping -> ready
    ((True, True, True, True, False, False), True),
    ((False, True, True, True, False, False), False),
    ((True, None, True, True, False, False), False),
    ((True, False, True, True, False, False), False),
    ((True, True, False, True, False, False), False),
    ((True, True, True, False, False, False), False),
    ((True, True, True, True, True, False), False),
    ((True, True, True, True, False, True), False),
]


@pytest.mark.parametrize(("flags", "ready"), READY)
def test_ready_needs_both_ends_its_subscriptions_and_a_taken_token(flags: tuple, ready: bool) -> None:
    mqtt_up, ngsi_up, subscribed, made, refused, stopping = flags
    health = NgsiHealth("b")
    health.set(mqtt_connected=mqtt_up, ngsi_connected=ngsi_up, subscribed=subscribed,
               subscriptions_made=made, token_refused=refused)
    snapshot = health.ngsi_snapshot(needs_subscription=True, needs_ngsi_subscriptions=True, stopping=stopping)
    assert snapshot.ready is ready and snapshot.mechanism == "mqtt-ngsi"
