"""The operator's verbs, in process: the stop flag's file, the command line's pure parts, the
agent routes' errors, and BrokerManager with real Mosquitto brokers (no fakes). The agent as a
subprocess, Kafka and the command line end to end: tests/integration/test_lifecycle_verbs.py."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
from flask.testing import FlaskClient

from engine import netutil, process
from engine.agent.app import AgentState, create_app
from engine.agent.held import HELD_FILE, clear_held, read_held, write_held
from engine.agent.manager import BrokerHeldError, BrokerManager, BrokerNotFoundError
from engine.agent.procs import SpawnedProcess, proc_info, processes_mentioning
from engine.cli.lifecycle import LifecycleError, broker_id_of, describe
from engine.drivers.registry import DriverRegistry
from engine.errors import WaitTimeoutError
from engine.model import BrokerSpec, BrokerStatus, ObservedBroker, ObservedTopic

REGISTRY = DriverRegistry.from_entry_points()
TOKEN = "test-token-0123456789abcdef"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def mqtt(broker_id: str = "m1") -> BrokerSpec:
    return BrokerSpec(id=broker_id, iri=f"urn:plant:{broker_id}", name=broker_id,
                      kind="mosquitto", host="127.0.0.1", port=netutil.free_port())


# --- the flag's file -------------------------------------------------------------------------

def test_the_flag_keeps_the_topics_and_goes_with_start(tmp_path: Path) -> None:
    assert read_held(tmp_path) is None
    topics = [ObservedTopic(name="b", partitions=2, replication_factor=1, retention_ms=1000),
              ObservedTopic(name="a", partitions=1)]
    written = write_held(tmp_path, topics)
    read = read_held(tmp_path)
    assert read == written and [t.name for t in read.topics] == ["a", "b"]
    assert read.topics[1].partitions == 2 and read.since > 0
    clear_held(tmp_path)
    assert read_held(tmp_path) is None
    clear_held(tmp_path)  # idempotent


@pytest.mark.parametrize("text", ["", "not json", "[1, 2]", '{"since": "x", "topics": [{"x": 1}]}'])
def test_a_damaged_flag_still_means_stopped(tmp_path: Path, text: str) -> None:
    (tmp_path / HELD_FILE).write_text(text, encoding="utf-8")
    held = read_held(tmp_path)
    assert held is not None and held.topics == ()


# --- the command line's pure parts ---------------------------------------------------------------

@pytest.mark.parametrize(("text", "expected"), [
    ("mosquitto", "mosquitto"), ("broker.mosquitto", "mosquitto"), ("kafka-1", "kafka-1"),
    ("broker.a.b", "a.b"), ("cell.kafka", "cell.kafka"),
])
def test_broker_ids(text: str, expected: str) -> None:
    assert broker_id_of(text) == expected


@pytest.mark.parametrize(("text", "message"), [
    ("topic.kafka.robot.pose", "is a topic"), ("bridge.a.b", "is a bridge"),
    ("broker.", "not a broker id"), ("-x", "not a broker id"), ("a/b", "not a broker id"),
])
def test_what_is_not_a_broker_is_refused(text: str, message: str) -> None:
    with pytest.raises(LifecycleError) as info:
        broker_id_of(text)
    assert message in info.value.message and info.value.exit_code == 2


def test_describe_says_what_the_broker_is_now() -> None:
    spec = mqtt()
    before = ObservedBroker(spec=spec, status=BrokerStatus.RUNNING, pid=10)
    after = ObservedBroker(spec=spec, status=BrokerStatus.RUNNING, pid=11)
    stopped = ObservedBroker(spec=spec, status=BrokerStatus.STOPPED_BY_OPERATOR)
    assert describe("restart", "h", before, after) == "broker.m1 on h: running, pid 10 → 11"
    assert describe("start", "h", stopped, after) == "broker.m1 on h: running, pid 11"
    assert "stopped-by-operator" in describe("stop", "h", before, stopped)
    assert "`plantkg start m1`" in describe("stop", "h", before, stopped)


# --- BrokerManager and the routes, with real Mosquitto ----------------------------------------------

@pytest.fixture
def opened(tmp_path: Path) -> Iterator[list[BrokerManager]]:
    managers: list[BrokerManager] = []
    yield managers
    for manager in managers:
        manager.close(stop_brokers=True)
    left = processes_mentioning(tmp_path)
    assert not left, f"processes left: {left}"


def open_manager(tmp_path: Path, opened: list[BrokerManager]) -> BrokerManager:
    manager = BrokerManager(tmp_path / "state", REGISTRY, backoff_base=0.1, tick=0.05).open()
    opened.append(manager)
    return manager


def test_stop_start_restart_in_process(tmp_path: Path, opened: list[BrokerManager]) -> None:
    manager = open_manager(tmp_path, opened)
    spec = mqtt()
    first = manager.put(spec)
    stopped = manager.stop("m1")
    assert stopped.status is BrokerStatus.STOPPED_BY_OPERATOR and proc_info(first.pid) is None
    # The supervisor (every 0.05 s) does not start it.
    with pytest.raises(WaitTimeoutError):
        process.wait_until(lambda: manager.get("m1").pid, 0.5, 0.02, what="no start")
    with pytest.raises(BrokerHeldError) as info:
        manager.put(spec)
    assert "plantkg start m1" in (info.value.hint or "")
    started = manager.start("m1")
    assert started.status is BrokerStatus.RUNNING and netutil.port_open("127.0.0.1", spec.port)
    restarted = manager.restart("m1")
    assert restarted.pid not in (None, started.pid) and proc_info(started.pid) is None
    with pytest.raises(BrokerNotFoundError):
        manager.stop("nope")


def test_a_process_left_by_a_crash_during_stop_is_stopped(tmp_path: Path,
                                                          opened: list[BrokerManager]) -> None:
    """The flag is written before the process is stopped: an agent that died in between leaves
    a running broker with the flag; the next agent stops it rather than adopting it."""
    manager = open_manager(tmp_path, opened)
    running = manager.put(mqtt())
    folder = tmp_path / "state" / "brokers" / "m1"
    write_held(folder, [])
    child = next(b.proc for b in manager._all() if isinstance(b.proc, SpawnedProcess))
    manager.close(stop_brokers=False)  # the agent "dies"; the broker runs on
    assert proc_info(running.pid) is not None
    again = open_manager(tmp_path, opened)
    assert again.get("m1").status is BrokerStatus.STOPPED_BY_OPERATOR
    process.wait_until(lambda: child.child.popen.poll() is not None, 10.0, 0.02,
                       what="the stray broker to be stopped")
    assert again.get("m1").pid is None and not (folder / "pid.json").exists()


@pytest.fixture
def client(tmp_path: Path, opened: list[BrokerManager]) -> FlaskClient:
    return create_app(AgentState(open_manager(tmp_path, opened), TOKEN)).test_client()


@pytest.mark.parametrize(("method", "path", "body", "status", "field"), [
    ("post", "/v1/brokers/nope/stop", None, 404, None),
    ("post", "/v1/brokers/nope/start", None, 404, None),
    ("post", "/v1/brokers/nope/restart", None, 404, None),
    ("post", "/v1/brokers/-bad/stop", None, 400, "id"),
    ("post", "/v1/brokers/m1/stop", "{}", 400, "body"),
    ("get", "/v1/brokers/m1/stop", None, 405, None),
])
def test_route_errors(client: FlaskClient, method: str, path: str, body: str | None, status: int,
                      field: str | None) -> None:
    response = getattr(client, method)(path, data=body, headers=AUTH)
    assert response.status_code == status
    answer = response.get_json()
    assert answer["error"] and answer.get("field") == field


def test_the_routes_need_the_token(client: FlaskClient) -> None:
    assert client.post("/v1/brokers/m1/stop").status_code == 401


def test_the_routes_answer_the_broker(client: FlaskClient) -> None:
    spec = mqtt()
    body = json.dumps({"id": spec.id, "iri": spec.iri, "name": spec.name, "kind": spec.kind,
                       "host": spec.host, "port": spec.port})
    assert client.put("/v1/brokers/m1", data=body, headers={**AUTH, "Content-Type":
                                                            "application/json"}).status_code == 200
    stopped = client.post("/v1/brokers/m1/stop", headers=AUTH)
    assert stopped.status_code == 200 and stopped.get_json()["status"] == "stopped-by-operator"
    assert client.get("/v1/brokers/m1", headers=AUTH).get_json()["status"] == "stopped-by-operator"
    refused = client.put("/v1/brokers/m1", data=body, headers={**AUTH, "Content-Type":
                                                               "application/json"})
    assert refused.status_code == 409 and "stopped by the operator" in refused.get_json()["error"]
    started = client.post("/v1/brokers/m1/start", headers=AUTH)
    assert started.status_code == 200 and started.get_json()["status"] == "running"
    restarted = client.post("/v1/brokers/m1/restart", headers=AUTH).get_json()
    assert restarted["pid"] != started.get_json()["pid"]
