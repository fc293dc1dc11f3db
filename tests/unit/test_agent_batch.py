"""POST /v1/batch against the agent's Flask app with a real state dir and real Mosquitto brokers:
lanes run at the same time, items of a lane in order, a result per item; a failed item skips the
rest of its lane only; a malformed batch is refused whole and nothing is done."""

from __future__ import annotations

import json
import socket
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from flask.testing import FlaskClient

from engine import netutil
from engine.agent.app import AgentState, create_app
from engine.agent.batch import MAX_LANES, parse_batch
from engine.agent.manager import BrokerManager
from engine.agent.procs import processes_mentioning
from engine.agent.wire import WireError
from engine.drivers.mosquitto.driver import MosquittoDriver
from engine.drivers.registry import DriverRegistry
from engine.errors import AccessNotSpreadError
from engine.model import BrokerStatus
from tests.unit.test_agent_app import AUTH, TOKEN, spec, topic


@pytest.fixture
def state(tmp_path: Path) -> Iterator[AgentState]:
    manager = BrokerManager(tmp_path / "state", DriverRegistry([MosquittoDriver()])).open()
    yield AgentState(manager, TOKEN, "test-agent")
    manager.close(stop_brokers=True)
    assert not processes_mentioning(tmp_path)


@pytest.fixture
def client(state: AgentState) -> FlaskClient:
    return create_app(state).test_client()


def batch(client: FlaskClient, lanes: list, **extra: object):  # type: ignore[no-untyped-def]
    return client.post("/v1/batch", data=json.dumps({"lanes": lanes, **extra}),
                       headers={**AUTH, "Content-Type": "application/json"})


def test_lanes_of_brokers_and_topics_run_and_answer_per_item(client: FlaskClient, state: AgentState) -> None:
    a, b = spec("a"), spec("b")
    response = batch(client, [
        [{"op": "put_broker", "spec": a, "owner": "cell"}, {"op": "put_topic", "spec": topic("x/1", "a"), "owner": "cell"}],
        [{"op": "put_broker", "spec": b}, {"op": "put_topic", "spec": topic("y", "b", qos=1)}],
    ], observe=True)
    assert response.status_code == 200, response.get_data(as_text=True)
    body = response.get_json()
    assert [[r["outcome"] for r in lane] for lane in body["lanes"]] == [["done", "done"], ["done", "done"]]
    first = body["lanes"][0][0]
    assert first["status"] == 200 and first["answer"]["status"] == "running" and first["answer"]["owner"] == "cell"
    assert body["lanes"][1][1]["answer"] == {**body["lanes"][1][1]["answer"], "name": "y", "qos": 1}
    # observe: what GET /v1/brokers and GET /v1/bridges answer now
    listed = client.get("/v1/brokers", headers=AUTH).get_json()["brokers"]
    assert body["brokers"] == listed and body["bridges"] == []
    assert {b["spec"]["id"]: [t["name"] for t in b["topics"]] for b in listed} == {"a": ["x/1"], "b": ["y"]}
    # again: idempotent, the same processes
    pids = {b["spec"]["id"]: b["pid"] for b in listed}
    again = batch(client, [[{"op": "put_broker", "spec": a}], [{"op": "put_broker", "spec": b}]]).get_json()
    assert {lane[0]["answer"]["spec"]["id"]: lane[0]["answer"]["pid"] for lane in again["lanes"]} == pids
    assert "brokers" not in again  # not asked to observe
    # deletes in a batch: topic, then broker, in its lane
    gone = batch(client, [[{"op": "delete_topic", "broker_id": "a", "name": "x/1"},
                           {"op": "delete_broker", "broker_id": "a"}],
                          [{"op": "delete_broker", "broker_id": "b"}]]).get_json()
    assert [[(r["outcome"], r["status"]) for r in lane] for lane in gone["lanes"]] == [
        [("done", 204), ("done", 204)], [("done", 204)]]
    assert state.brokers.list() == []


def test_a_failed_item_skips_the_rest_of_its_lane_only(client: FlaskClient, state: AgentState) -> None:
    with socket.create_server(("127.0.0.1", 0)) as taken:  # the first broker cannot bind its port
        response = batch(client, [
            [{"op": "put_broker", "spec": spec("bad", port=taken.getsockname()[1])},
             {"op": "put_topic", "spec": topic("t", "bad")}],
            [{"op": "put_topic", "spec": topic("t", "nowhere")}, {"op": "delete_broker", "broker_id": "nowhere"}],
            [{"op": "put_broker", "spec": spec("good")}],
        ])
    body = response.get_json()
    assert response.status_code == 200
    (bad, bad_topic), (missing, not_tried), (good,) = body["lanes"]
    assert bad["outcome"] == "failed" and bad["status"] == 422 and "Address already in use" in bad["error"]["error"]
    assert bad["error"]["retryable"] is False
    assert bad_topic == {"outcome": "skipped"} and not_tried == {"outcome": "skipped"}
    assert missing["status"] == 404 and "no broker 'nowhere'" in missing["error"]["error"]
    assert good["outcome"] == "done" and good["answer"]["status"] == "running"
    assert state.brokers.get("good").status is BrokerStatus.RUNNING  # type: ignore[union-attr]
    assert [t.name for t in state.brokers.get("bad").topics] == []  # type: ignore[union-attr]


def test_an_owner_conflict_is_a_409_of_its_item(client: FlaskClient) -> None:
    a = spec("a")
    assert batch(client, [[{"op": "put_broker", "spec": a, "owner": "one"}]]).status_code == 200
    body = batch(client, [[{"op": "put_topic", "spec": topic("t", "a"), "owner": "two"}],
                          [{"op": "delete_broker", "broker_id": "a", "owner": "two"}]]).get_json()
    assert [lane[0]["status"] for lane in body["lanes"]] == [409, 409]
    assert "owned by plant 'one'" in body["lanes"][1][0]["error"]["error"]


GOOD = {"op": "put_broker", "spec": {"id": "first", "iri": "urn:first", "name": "m", "kind": "mosquitto",
                                    "host": "127.0.0.1", "port": netutil.free_port()}}


@pytest.mark.parametrize(("body", "field"), [
    ({"lanes": "x"}, "lanes"),
    ({"lanes": [[GOOD], []]}, "lanes[1]"),
    ({"lanes": [[GOOD]], "extra": 1}, "extra"),
    ({"lanes": [[GOOD], ["x"]]}, "lanes[1][0]"),
    ({"lanes": [[GOOD], [{"op": "restart_broker", "broker_id": "a"}]]}, "lanes[1][0].op"),
    ({"lanes": [[GOOD, {"op": "put_broker"}]]}, "lanes[0][1].spec"),
    ({"lanes": [[GOOD], [{"op": "delete_broker", "broker_id": "a", "extra": 1}]]}, "lanes[1][0].extra"),
    ({"lanes": [[GOOD], [{"op": "delete_broker", "broker_id": "../a"}]]}, "lanes[1][0].broker_id"),
    ({"lanes": [[GOOD], [{"op": "delete_topic", "broker_id": "a", "name": ""}]]}, "lanes[1][0].name"),
    ({"lanes": [[GOOD], [{"op": "delete_broker", "broker_id": "a", "owner": "two words"}]]},
     "lanes[1][0].owner"),
    ({"lanes": [[GOOD], [{"op": "put_topic", "spec": {"broker_id": "a", "name": "t"}}]]}, "lanes[1][0].spec.iri"),
])
def test_a_malformed_batch_is_refused_whole_naming_the_field(client: FlaskClient, state: AgentState,
                                                             body: dict, field: str) -> None:
    response = client.post("/v1/batch", data=json.dumps(body), headers={**AUTH, "Content-Type": "application/json"})
    assert response.status_code == 400
    answer = response.get_json()
    assert answer["field"] == field, answer
    assert state.brokers.list() == []  # nothing done, not even the good lane


def test_spec_errors_name_the_items_field() -> None:
    with pytest.raises(WireError) as info:
        parse_batch({"lanes": [[{"op": "put_broker", "spec": {**spec("a"), "port": 70000}}]]})
    assert info.value.field == "lanes[0][0].spec.port"
    with pytest.raises(WireError, match="at most"):
        parse_batch({"lanes": [[{"op": "delete_broker", "broker_id": "a"}]] * (MAX_LANES + 1)})
    with pytest.raises(WireError) as info:
        parse_batch({"lanes": [], "observe": "yes"})
    assert info.value.field == "observe"


def test_lanes_start_their_brokers_together(tmp_path: Path) -> None:
    """Two brokers each healthy only once the other listens: passes only if both are spawned
    before either is awaited (one after the other, the first would wait for the second forever)."""
    ports = {"a": netutil.free_port(), "b": netutil.free_port()}

    class Together(MosquittoDriver):
        start_deadline = 5.0

        def health(self, spec, timeout):  # type: ignore[no-untyped-def]
            other = ports["b" if spec.id == "a" else "a"]
            return netutil.port_open("127.0.0.1", other, timeout=0.05) and super().health(spec, timeout)

    manager = BrokerManager(tmp_path / "state", DriverRegistry([Together()])).open()
    try:
        client = create_app(AgentState(manager, TOKEN)).test_client()
        body = batch(client, [[{"op": "put_broker", "spec": spec("a", port=ports["a"])}],
                              [{"op": "put_broker", "spec": spec("b", port=ports["b"])}]]).get_json()
        assert [lane[0]["outcome"] for lane in body["lanes"]] == ["done", "done"], body
    finally:
        manager.close(stop_brokers=True)
    assert not processes_mentioning(tmp_path)


def test_a_batch_of_brokers_all_come_up_and_all_go_down(client: FlaskClient, state: AgentState,
                                                         tmp_path: Path) -> None:
    """N brokers in one batch (each with a topic after it in its lane): all running and answering;
    one batch deletes them all: no process of theirs is left, every folder moved to removed/."""
    n = 12
    ids = [f"m{i}" for i in range(n)]
    body = batch(client, [[{"op": "put_broker", "spec": spec(i)}, {"op": "put_topic", "spec": topic("t", i)}]
                          for i in ids], observe=True).get_json()
    assert [[r["outcome"] for r in lane] for lane in body["lanes"]] == [["done", "done"]] * n, body
    assert sorted(b["spec"]["id"] for b in body["brokers"] if b["status"] == "running") == sorted(ids)
    pids = {b["spec"]["id"]: b["pid"] for b in body["brokers"]}
    assert len(set(pids.values())) == n
    for b in body["brokers"]:
        assert netutil.port_open(b["spec"]["host"], b["spec"]["port"], timeout=1.0), b
    assert len(processes_mentioning(tmp_path / "state" / "brokers")) == n

    gone = batch(client, [[{"op": "delete_topic", "broker_id": i, "name": "t"},
                           {"op": "delete_broker", "broker_id": i}] for i in ids]).get_json()
    assert [[(r["outcome"], r["status"]) for r in lane] for lane in gone["lanes"]] == [
        [("done", 204), ("done", 204)]] * n, gone
    assert state.brokers.list() == []
    assert not processes_mentioning(tmp_path / "state")
    for pid in pids.values():
        assert not Path(f"/proc/{pid}").exists() or "zombie" in Path(f"/proc/{pid}/status").read_text().lower()
    assert sorted(p.name.split(".")[0] for p in (tmp_path / "state" / "removed").iterdir()) == sorted(ids)
    assert list((tmp_path / "state" / "brokers").iterdir()) == []


def test_one_bad_broker_in_a_batch_fails_alone_with_its_own_error(client: FlaskClient, state: AgentState,
                                                                   tmp_path: Path) -> None:
    """Among N brokers started together, one whose port is taken: it alone fails (422, Mosquitto's
    own words), runs no process and gets no topic; the others run, and their lanes go on."""
    good = [f"g{i}" for i in range(6)]
    with socket.create_server(("127.0.0.1", 0)) as taken:
        lanes = [[{"op": "put_broker", "spec": spec(i)}, {"op": "put_topic", "spec": topic("t", i)}] for i in good]
        lanes.insert(3, [{"op": "put_broker", "spec": spec("bad", port=taken.getsockname()[1])},
                         {"op": "put_topic", "spec": topic("t", "bad")}])
        body = batch(client, lanes).get_json()
    results = body["lanes"]
    bad, bad_topic = results.pop(3)
    assert bad["outcome"] == "failed" and bad["status"] == 422, bad
    assert "'bad'" in bad["error"]["error"] and "Address already in use" in bad["error"]["error"]
    assert bad_topic == {"outcome": "skipped"}
    assert [[r["outcome"] for r in lane] for lane in results] == [["done", "done"]] * len(good)
    observed = state.brokers.get("bad")
    assert observed is not None and observed.status is BrokerStatus.FAILED and observed.pid is None
    assert observed.topics == () and "Address already in use" in (observed.last_error or "")
    assert not processes_mentioning(tmp_path / "state" / "brokers" / "bad")
    assert all(state.brokers.get(i).status is BrokerStatus.RUNNING for i in good)  # type: ignore[union-attr]


def test_a_batch_may_name_one_broker_in_two_lanes(client: FlaskClient, state: AgentState) -> None:
    """The same broker in two lanes: its items take turns (no step of all brokers at once)."""
    a = spec("a")
    body = batch(client, [[{"op": "put_broker", "spec": a}], [{"op": "put_broker", "spec": a}],
                          [{"op": "put_broker", "spec": spec("b")}]]).get_json()
    assert [lane[0]["outcome"] for lane in body["lanes"]] == ["done", "done", "done"], body
    assert body["lanes"][0][0]["answer"]["pid"] == body["lanes"][1][0]["answer"]["pid"]


def test_a_broker_is_healthy_only_once_its_port_accepts_connections(tmp_path: Path) -> None:
    """The agent asks the driver's health check only once the broker's port accepts TCP: a process
    that never listens stays 'starting' (503 at the deadline), whatever its health check says."""
    class NeverListens(MosquittoDriver):
        start_deadline = 0.5

        def command(self, spec, broker_dir):  # type: ignore[no-untyped-def]
            return ["sleep", "30"]

        def health(self, spec, timeout):  # type: ignore[no-untyped-def]
            return True

    manager = BrokerManager(tmp_path / "state", DriverRegistry([NeverListens()])).open()
    try:
        client = create_app(AgentState(manager, TOKEN)).test_client()
        (result,) = batch(client, [[{"op": "put_broker", "spec": spec("a")}]]).get_json()["lanes"][0]
        assert result["outcome"] == "failed" and result["status"] == 503, result
        assert "still starting" in result["error"]["error"] and result["error"]["retryable"] is True
    finally:
        manager.close(stop_brokers=True)
    assert not processes_mentioning(tmp_path)


def test_a_settling_driver_is_waited_for_after_health_and_on_every_put(tmp_path: Path) -> None:
    """A driver that must settle (a closed Kafka cluster's lead, engine.drivers.base.Settling) is
    asked once its broker is healthy; its error is the PUT's answer (the broker keeps running),
    and a PUT of the unchanged broker asks it again."""
    calls: list[tuple[str, bool]] = []

    class Lags(MosquittoDriver):
        def settle(self, spec):  # type: ignore[no-untyped-def]
            calls.append((spec.id, manager.get(spec.id).status is BrokerStatus.RUNNING))  # type: ignore[union-attr]
            if len(calls) == 1:
                raise AccessNotSpreadError("c", "127.0.0.9:9092", ("lacks user 'hmi'",), 0.1)

    manager = BrokerManager(tmp_path / "state", DriverRegistry([Lags()])).open()
    try:
        client = create_app(AgentState(manager, TOKEN)).test_client()
        a = spec("a")
        (first,) = batch(client, [[{"op": "put_broker", "spec": a}]]).get_json()["lanes"][0]
        assert first["outcome"] == "failed" and first["status"] == 503, first
        assert "node 127.0.0.9:9092" in first["error"]["error"] and first["error"]["retryable"] is True
        assert manager.get("a").status is BrokerStatus.RUNNING  # type: ignore[union-attr]
        (again,) = batch(client, [[{"op": "put_broker", "spec": a}]]).get_json()["lanes"][0]
        assert again["outcome"] == "done", again
        assert calls == [("a", True), ("a", True)]
    finally:
        manager.close(stop_brokers=True)
    assert not processes_mentioning(tmp_path)
