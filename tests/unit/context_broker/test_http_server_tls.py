"""The context broker's HTTP server with TLS (``pk:tls true``; engine/context_broker/http_server.py
with an ``ssl_context``) on real sockets: a client trusting the plant CA is answered over HTTPS, a
plain HTTP client gets no answer, a client trusting another CA and a client limited to TLS 1.1 fail
the handshake, and a client that connects and never says hello blocks nobody."""

from __future__ import annotations

import http.client
import json
import socket
import ssl
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from engine.context_broker.http_server import HttpServer
from engine.netutil import free_port
from engine.security import ca, https
from tests.unit.context_broker.test_http_server import serving

HOST = "127.0.0.1"


def app(environ: dict[str, Any], start_response: Any) -> list[bytes]:
    body = json.dumps({"scheme": environ["wsgi.url_scheme"], "path": environ["PATH_INFO"]}).encode()
    start_response("200 OK", [("Content-Type", "application/json"), ("Content-Length", str(len(body)))])
    return [body]


@pytest.fixture
def plant_ca(tmp_path: Path) -> ca.Ca:
    return ca.load_or_create_ca(tmp_path / "plant-ca")


@contextmanager
def tls_served(wsgi: Any, folder: Path, authority: ca.Ca) -> Iterator[HttpServer]:
    """``wsgi`` served over HTTPS on a free port of HOST, with a certificate for HOST that
    ``authority`` signed (its files in ``folder``)."""
    cert, key = ca.issue_server_cert(authority, (HOST,), name="test context broker")
    (folder / "cert.pem").write_bytes(cert)
    (folder / "key.pem").write_bytes(key)
    context = https.server_context(folder / "cert.pem", folder / "key.pem")
    with serving(HttpServer(wsgi, HOST, free_port(), threads=2, ssl_context=context)) as srv:
        yield srv


@pytest.fixture
def server(tmp_path: Path, plant_ca: ca.Ca) -> Iterator[HttpServer]:
    with tls_served(app, tmp_path, plant_ca) as srv:
        yield srv


def get(srv: HttpServer, context: ssl.SSLContext, path: str = "/version") -> dict[str, Any]:
    conn = http.client.HTTPSConnection(HOST, srv.port, timeout=10, context=context)
    try:
        conn.request("GET", path)
        answer = conn.getresponse()
        assert answer.status == 200
        return json.loads(answer.read())
    finally:
        conn.close()


def test_a_client_trusting_the_plant_ca_is_answered_over_https(server: HttpServer, plant_ca: ca.Ca) -> None:
    assert get(server, https.client_context(plant_ca.cert_file)) == {"scheme": "https", "path": "/version"}


def test_a_plain_http_client_gets_no_answer(server: HttpServer) -> None:
    with socket.create_connection((HOST, server.port), timeout=10) as sock:
        sock.sendall(b"GET /version HTTP/1.1\r\nHost: x\r\n\r\n")
        got = b""
        try:
            while chunk := sock.recv(4096):
                got += chunk
        except ConnectionResetError:
            pass
    assert b"HTTP/" not in got and b"version" not in got


def test_a_client_trusting_another_ca_is_refused(server: HttpServer, tmp_path: Path) -> None:
    other = ca.load_or_create_ca(tmp_path / "other-ca")
    with pytest.raises(ssl.SSLCertVerificationError):
        get(server, https.client_context(other.cert_file))


@pytest.mark.filterwarnings("ignore:ssl.TLSVersion.TLSv1_1 is deprecated:DeprecationWarning")
def test_tls_older_than_1_2_is_refused(server: HttpServer, plant_ca: ca.Ca) -> None:
    old = https.client_context(plant_ca.cert_file)
    old.minimum_version = ssl.TLSVersion.MINIMUM_SUPPORTED
    old.maximum_version = ssl.TLSVersion.TLSv1_1
    with pytest.raises(ssl.SSLError):
        get(server, old)


def test_a_client_that_never_says_hello_blocks_nobody(server: HttpServer, plant_ca: ca.Ca) -> None:
    silent = [socket.create_connection((HOST, server.port), timeout=10) for _ in range(3)]
    try:  # the handshakes run on the event loop: the silent ones hold no thread
        assert get(server, https.client_context(plant_ca.cert_file))["scheme"] == "https"
    finally:
        for sock in silent:
            sock.close()
