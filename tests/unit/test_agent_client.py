"""AgentClient against a real agent server (in a thread, real WSGI server, real Mosquitto), and
the errors it maps: refused connection, silence, 401, 4xx, 503. Also the server's helpers: the
listen address, the token file, the state-dir lock."""

from __future__ import annotations

import os
import socket
import stat
from collections.abc import Iterator
from pathlib import Path

import pytest

from engine import netutil
from engine.agent.client import AgentClient
from engine.agent.procs import processes_mentioning
from engine.agent.server import (
    ListenAddress,
    RunningAgent,
    load_or_create_token,
    lock_state_dir,
    parse_listen,
    start_agent,
)
from engine.drivers.mosquitto.driver import MosquittoDriver
from engine.drivers.registry import DriverRegistry
from engine.errors import (
    AgentAuthError,
    EngineError,
    PermanentDispatchError,
    TemporaryDispatchError,
)
from engine.model import BrokerSpec, BrokerStatus, ObservedTopic, TopicSpec

TOKEN = "client-test-token-0123456789"


@pytest.fixture
def driver() -> MosquittoDriver:
    return MosquittoDriver()


@pytest.fixture
def agent(tmp_path: Path, driver: MosquittoDriver) -> Iterator[RunningAgent]:
    running = start_agent(ListenAddress("127.0.0.1", 0), tmp_path / "state", TOKEN,
                          registry=DriverRegistry([driver]))
    yield running
    running.shutdown(stop_brokers=True)
    assert not processes_mentioning(tmp_path)


@pytest.fixture
def client(agent: RunningAgent) -> AgentClient:
    return AgentClient(agent.address.url, TOKEN, timeout=10.0)


def mqtt(broker_id: str = "m1") -> BrokerSpec:
    return BrokerSpec(id=broker_id, iri=f"urn:plant:{broker_id}", name="MQTT", kind="mosquitto",
                      host="127.0.0.1", port=netutil.free_port())


def test_the_contract_round_trip(client: AgentClient) -> None:
    assert client.health()["status"] == "ok"
    assert client.list_brokers() == [] and client.get_broker("m1") is None
    spec = mqtt()
    observed = client.put_broker(spec)
    assert observed.spec == spec and observed.status is BrokerStatus.RUNNING and observed.pid
    assert client.put_broker(spec).pid == observed.pid
    name = "/cell/robot 1/pos"
    assert client.put_topic(TopicSpec("m1", name, "urn:t", qos=2)) == ObservedTopic(name, qos=2)
    listed = client.list_brokers()
    assert [b.spec for b in listed] == [spec] and listed[0].topics == (ObservedTopic(name, qos=2),)
    client.delete_topic("m1", name)
    assert client.get_broker("m1").topics == ()
    client.delete_broker("m1")
    client.delete_broker("m1")
    assert client.get_broker("m1") is None


def test_a_wrong_token_is_an_auth_error(agent: RunningAgent) -> None:
    with pytest.raises(AgentAuthError) as info:
        AgentClient(agent.address.url, "not-the-token").health()
    assert "401" in str(info.value) and "bearer token" in str(info.value)
    assert info.value.host == "127.0.0.1" and not info.value.retryable


def test_a_refused_request_is_permanent_with_the_agent_message(client: AgentClient) -> None:
    with pytest.raises(PermanentDispatchError) as info:
        client.put_broker(BrokerSpec("m1", "urn:m1", "MQTT", "activemq", "127.0.0.1", 1883))
    assert "422" in info.value.message and "no driver for broker kind 'activemq'" in info.value.message
    assert info.value.hint and not isinstance(info.value, AgentAuthError)
    with pytest.raises(PermanentDispatchError, match="port"):
        client.put_broker(BrokerSpec("m1", "urn:m1", "MQTT", "mosquitto", "127.0.0.1", 70000))
    with pytest.raises(PermanentDispatchError, match="must not contain \\+ or #"):
        client.put_broker(mqtt())
        client.put_topic(TopicSpec("m1", "a/#", "urn:t"))


def test_503_is_temporary(client: AgentClient, driver: MosquittoDriver,
                          monkeypatch: pytest.MonkeyPatch) -> None:
    # A real agent answering 503: the broker is still starting when the start deadline passes
    # (its health check never passes here, so the answer does not depend on the machine's speed).
    driver.start_deadline = 0.2
    monkeypatch.setattr(driver, "health", lambda spec, timeout: False)
    spec = mqtt()
    with pytest.raises(TemporaryDispatchError) as info:
        client.put_broker(spec)
    assert "503" in info.value.message and info.value.retryable
    driver.start_deadline = 10.0
    monkeypatch.undo()  # the broker answers again: the retried PUT succeeds
    assert client.put_broker(spec).status is BrokerStatus.RUNNING


def test_a_refused_connection_is_temporary() -> None:
    port = netutil.free_port()
    with pytest.raises(TemporaryDispatchError, match="cannot reach the agent"):
        AgentClient(f"http://127.0.0.1:{port}", TOKEN).health()


def test_a_silent_agent_is_temporary() -> None:
    with socket.create_server(("127.0.0.1", 0)) as silent:  # accepts, never answers
        client = AgentClient(f"http://127.0.0.1:{silent.getsockname()[1]}", TOKEN, timeout=0.3)
        with pytest.raises(TemporaryDispatchError, match="no answer within"):
            client.health()


def test_the_client_never_prints_its_token() -> None:
    assert TOKEN not in repr(AgentClient("http://127.0.0.1:7300", TOKEN))
    with pytest.raises(ValueError):
        AgentClient("127.0.0.1:7300", TOKEN)


# --- server helpers ------------------------------------------------------------------------

@pytest.mark.parametrize(("text", "host", "port"), [
    ("127.0.0.1:7301", "127.0.0.1", 7301),
    ("127.0.0.2", "127.0.0.2", 7300),
    ("localhost:0", "127.0.0.1", 0),
    ("[::1]:7302", "::1", 7302),
    ("::1", "::1", 7300),
])
def test_parse_listen(text: str, host: str, port: int) -> None:
    assert parse_listen(text) == ListenAddress(host, port)


@pytest.mark.parametrize("text", ["0.0.0.0:7300", "192.168.1.10:7300", "[::]:7300"])
def test_a_network_address_needs_allow_remote(text: str) -> None:
    with pytest.raises(EngineError, match="--allow-remote"):
        parse_listen(text)
    assert parse_listen(text, allow_remote=True).port == 7300


@pytest.mark.parametrize("text", ["agent.local:7300", "127.0.0.1:http", "127.0.0.1:70000", "[::1"])
def test_bad_listen_addresses(text: str) -> None:
    with pytest.raises(EngineError):
        parse_listen(text)


def test_token_file(tmp_path: Path) -> None:
    path = tmp_path / "token"
    token, created = load_or_create_token(path)
    assert created and len(token) >= 32
    assert stat.S_IMODE(path.stat().st_mode) == 0o600
    assert load_or_create_token(path) == (token, False)
    path.write_text("short\n")
    with pytest.raises(EngineError, match="not a usable token"):
        load_or_create_token(path)
    with pytest.raises(EngineError, match="cannot create the token file"):
        load_or_create_token(tmp_path / "missing" / "token")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["token"]


def test_one_agent_per_state_dir(tmp_path: Path) -> None:
    first = lock_state_dir(tmp_path)
    try:
        with pytest.raises(EngineError, match=f"another agent \\(pid {os.getpid()}\\)"):
            lock_state_dir(tmp_path)
    finally:
        first.close()
    lock_state_dir(tmp_path).close()


def test_a_taken_port_is_a_clear_error(tmp_path: Path) -> None:
    with socket.create_server(("127.0.0.1", 0)) as taken:
        with pytest.raises(EngineError, match="cannot listen on"):
            start_agent(ListenAddress("127.0.0.1", taken.getsockname()[1]), tmp_path, TOKEN,
                        registry=DriverRegistry([MosquittoDriver()]))
    lock_state_dir(tmp_path).close()  # the failed start released the lock


def test_a_worker_that_will_not_stop_leaves_no_broker_running(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Shutdown with stop_brokers: the bridge workers' close raises (a worker that could not be
    stopped); the brokers are stopped all the same and the state dir's lock is released."""
    running = start_agent(ListenAddress("127.0.0.1", 0), tmp_path / "state", TOKEN,
                          registry=DriverRegistry([MosquittoDriver()]))
    spec = mqtt()
    AgentClient(running.address.url, TOKEN, timeout=10.0).put_broker(spec)
    assert netutil.port_open(spec.host, spec.port)

    def will_not_stop(*, stop_workers: bool = False) -> None:
        raise OSError("bridge worker w1 could not be stopped")

    assert running.workers is not None
    monkeypatch.setattr(running.workers, "close", will_not_stop)
    with pytest.raises(OSError, match="could not be stopped"):
        running.shutdown(stop_brokers=True)
    assert not netutil.port_open(spec.host, spec.port)
    assert not processes_mentioning(tmp_path)
    lock_state_dir(tmp_path / "state").close()  # released
