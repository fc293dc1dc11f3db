"""The agent's server keeps connections open between requests (engine.agent.keepalive), against
a real agent in a thread: several requests on one socket, bodies the app did not read drained
exactly, Connection: close where keeping is not safe, kept connections ended when the agent
stops; and AgentClient reusing its connection, and retrying once on one the agent closed."""

from __future__ import annotations

import http.client
import json
import socket
from collections.abc import Iterator
from pathlib import Path

import pytest

from engine.agent.client import AgentClient
from engine.agent.procs import processes_mentioning
from engine.agent.server import ListenAddress, RunningAgent, start_agent
from engine.drivers.mosquitto.driver import MosquittoDriver
from engine.drivers.registry import DriverRegistry

TOKEN = "keepalive-test-token-0123456789"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def start(state: Path, port: int = 0) -> RunningAgent:
    return start_agent(ListenAddress("127.0.0.1", port), state, TOKEN, registry=DriverRegistry([MosquittoDriver()]))


@pytest.fixture
def agent(tmp_path: Path) -> Iterator[RunningAgent]:
    running = start(tmp_path / "state")
    yield running
    running.shutdown(stop_brokers=True)
    assert not processes_mentioning(tmp_path)


def connect(agent: RunningAgent) -> http.client.HTTPConnection:
    return http.client.HTTPConnection("127.0.0.1", agent.address.port, timeout=10)


def test_many_requests_share_one_connection(agent: RunningAgent) -> None:
    conn = connect(agent)
    conn.request("GET", "/v1/health", headers=AUTH)
    first = conn.getresponse()
    assert first.status == 200 and not first.will_close
    json.loads(first.read())
    sock = conn.sock
    for path in ("/v1/brokers", "/v1/bridges", "/v1/brokers/none"):
        conn.request("GET", path, headers=AUTH)
        answer = conn.getresponse()
        assert answer.status in (200, 404) and json.loads(answer.read())
        assert conn.sock is sock  # the same connection, not a new one
    conn.close()


def test_a_body_the_app_did_not_read_is_drained_and_the_next_request_is_intact(agent: RunningAgent) -> None:
    conn = connect(agent)
    body = json.dumps({"pad": "x" * 200_000}).encode()
    conn.request("PUT", "/v1/brokers/m1", body=body, headers={"Content-Type": "application/json"})  # no token
    refused = conn.getresponse()
    assert refused.status == 401 and not refused.will_close
    refused.read()
    conn.request("GET", "/v1/health", headers=AUTH)
    assert conn.getresponse().status == 200
    conn.close()


def test_http_1_0_and_chunked_requests_are_answered_and_closed(agent: RunningAgent) -> None:
    with socket.create_connection(("127.0.0.1", agent.address.port), timeout=10) as raw:
        raw.sendall(b"GET /v1/health HTTP/1.0\r\nAuthorization: Bearer " + TOKEN.encode() + b"\r\n\r\n")
        answer = _read_all(raw)
    assert answer.startswith(b"HTTP/1.1 200") and b"Connection: close" in answer
    with socket.create_connection(("127.0.0.1", agent.address.port), timeout=10) as raw:
        raw.sendall(b"PUT /v1/brokers/m1 HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer " + TOKEN.encode()
                    + b"\r\nContent-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n"
                    b"2\r\n{}\r\n0\r\n\r\n")
        answer = _read_all(raw)
    assert answer.startswith(b"HTTP/1.1 400") and b"Connection: close" in answer


def _read_all(sock: socket.socket) -> bytes:
    chunks = []
    while data := sock.recv(65536):
        chunks.append(data)
    return b"".join(chunks)


def test_stopping_the_agent_ends_its_kept_connections(tmp_path: Path) -> None:
    agent = start(tmp_path / "state")
    conn = connect(agent)
    conn.request("GET", "/v1/health", headers=AUTH)
    conn.getresponse().read()
    agent.shutdown()
    conn.sock.settimeout(10)
    assert conn.sock.recv(1) == b""  # closed by the agent: no thread still answers for it
    conn.close()


def test_the_client_keeps_its_connection_and_survives_an_agent_restart(tmp_path: Path) -> None:
    agent = start(tmp_path / "state")
    client = AgentClient(agent.address.url, TOKEN, timeout=10)
    try:
        client.health()
        kept = list(client._idle)
        client.list_brokers()
        assert client._idle == kept and len(kept) == 1  # the same connection again
        port = agent.address.port
        agent.shutdown()
        agent = start(tmp_path / "state", port)  # same address: the kept connection is stale
        assert client.list_brokers() == []  # sent again on a new connection, transparently
        assert client._idle and client._idle != kept
    finally:
        client.close()
        agent.shutdown(stop_brokers=True)
    assert not processes_mentioning(tmp_path)
