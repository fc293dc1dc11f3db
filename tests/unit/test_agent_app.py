"""The agent's Flask app against a real state dir, with real Mosquitto brokers where a route
needs one (no fakes). Every test checks that no process of its tmp dir is left."""

from __future__ import annotations

import json
import socket
import threading
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import quote

import pytest
from flask.testing import FlaskClient

from engine import netutil
from engine.agent.app import AgentState, create_app
from engine.agent.manager import BrokerManager
from engine.agent.procs import processes_mentioning, proc_info
from engine.drivers.mosquitto.driver import MosquittoDriver
from engine.drivers.registry import DriverRegistry

TOKEN = "test-token-0123456789abcdef"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


def spec(broker_id: str = "m1", **changes) -> dict:
    values = {"id": broker_id, "iri": f"https://example.org/plant#{broker_id}", "name": "Cell MQTT",
              "kind": "mosquitto", "host": "127.0.0.1", "port": netutil.free_port()}
    return {**values, **changes}


def topic(name: str, broker_id: str = "m1", **changes) -> dict:
    return {"broker_id": broker_id, "name": name, "iri": "https://example.org/plant#t", **changes}


def url(broker_id: str, name: str | None = None) -> str:
    base = f"/v1/brokers/{broker_id}"
    return base if name is None else f"{base}/topics/{quote(name, safe='')}"


@pytest.fixture
def state(tmp_path: Path) -> Iterator[AgentState]:
    registry = DriverRegistry.from_entry_points()
    manager = BrokerManager(tmp_path / "state", registry, backoff_base=0.2).open()
    yield AgentState(manager, TOKEN, "test-agent")
    manager.close(stop_brokers=True)
    left = processes_mentioning(tmp_path)
    assert not left, f"processes left: {left}"


@pytest.fixture
def client(state: AgentState) -> FlaskClient:
    return create_app(state).test_client()


def put(client: FlaskClient, path: str, body: object, **kwargs):
    data = body if isinstance(body, (str, bytes)) else json.dumps(body)
    return client.put(path, data=data, headers={**AUTH, "Content-Type": "application/json"},
                      **kwargs)


def error(response) -> dict:
    body = response.get_json()
    assert set(body) >= {"error", "hint", "retryable"}, body
    return body


# --- authentication ------------------------------------------------------------------------

@pytest.mark.parametrize("header", [None, "Bearer wrong-token", f"Basic {TOKEN}", "Bearer",
                                    f"Bearer {TOKEN}x", f"bearer{TOKEN}"])
def test_every_route_needs_the_token(client: FlaskClient, header: str | None) -> None:
    headers = {"Authorization": header} if header is not None else {}
    for method, path in [("get", "/v1/health"), ("get", "/v1/brokers"), ("get", url("m1")),
                         ("put", url("m1")), ("delete", url("m1")), ("put", url("m1", "a/b")),
                         ("delete", url("m1", "a/b"))]:
        response = getattr(client, method)(path, headers=headers, json=spec())
        assert response.status_code == 401, (method, path)
        assert response.headers["WWW-Authenticate"].startswith("Bearer")
        assert error(response)["retryable"] is False


def test_health(client: FlaskClient) -> None:
    response = client.get("/v1/health", headers=AUTH)
    assert response.status_code == 200
    body = response.get_json()
    assert body["status"] == "ok" and body["agent"] == "test-agent"
    # The built-in drivers, sorted; an installed plugin package (plugins/) may add its own.
    assert body["drivers"] == sorted(body["drivers"]) and body["driver_errors"] == {}
    assert {"kafka", "mosquitto", "ngsi-v2"} <= set(body["drivers"])
    assert body["version"]


def test_openapi_needs_no_token_and_describes_every_route(client: FlaskClient) -> None:
    response = client.get("/v1/openapi.json")
    assert response.status_code == 200
    document = response.get_json()
    assert document["openapi"].startswith("3.1")
    routes = set()
    for rule in client.application.url_map.iter_rules():
        if rule.endpoint == "static":
            continue
        path = rule.rule.replace("<broker_id>", "{broker_id}").replace("<topic:name>", "{name}") \
            .replace("<remote_id>", "{remote_id}")
        for method in rule.methods - {"HEAD", "OPTIONS"}:
            routes.add((path, method.lower()))
    described = {(path, method) for path, item in document["paths"].items()
                 for method in item if method in ("get", "put", "post", "delete", "patch")}
    assert routes == described
    for path, item in document["paths"].items():
        for name in ("broker_id", "name"):
            if "{" + name + "}" in path:
                assert any(p["name"] == name for p in item["parameters"]), path


# --- validation ----------------------------------------------------------------------------

@pytest.mark.parametrize(("body", "field"), [
    ({**spec(), "extra": 1}, "extra"),
    ({k: v for k, v in spec().items() if k != "port"}, "port"),
    (spec(port=0), "port"),
    (spec(port=65536), "port"),
    (spec(port="1883"), "port"),
    (spec(port=True), "port"),
    (spec(port=1883.0), "port"),
    (spec(host="broker.local"), "host"),
    (spec(host="127.0.0.1\n"), "host"),
    (spec(name="Cell\nlistener 1 0.0.0.0"), "name"),
    (spec(name=""), "name"),
    (spec(iri="urn:a b"), "iri"),
    (spec(kind="Mosquitto"), "kind"),
    (spec(broker_id="m2"), "id"),
    (spec(tls=True, certificate_port=70000), "certificate_port"),
    (spec(certificate_port=8884), "certificate_port"),  # a certificate listener without TLS
    (spec(tls=True, certificate_port=8884, users=[{"name": "cam1"}]), "users[0].secret_ref"),
    ([spec()], "body"),
    ('{"id": "m1", "id": "m1"}', "id"),
    ('{"port": NaN}', "body"),
    ("{not json", "body"),
    ("", "body"),
    (b"\xff\xfe", "body"),
])
def test_bad_broker_bodies_are_refused_naming_the_field(client: FlaskClient, body, field: str,
                                                       state: AgentState) -> None:
    response = put(client, url("m1"), body)
    assert response.status_code == 400, response.get_json()
    answer = error(response)
    assert answer["field"] == field and field in answer["error"]
    assert answer["retryable"] is False
    assert state.brokers.list() == []


def test_the_spec_is_reported_as_given(client: FlaskClient) -> None:
    """An IPv6 address written long-hand is not compressed: observed equals desired."""
    body = spec(host="0:0:0:0:0:0:0:1", port=netutil.free_port("::1"))
    answer = put(client, url("m1"), body)
    assert answer.status_code == 200, answer.get_json()
    assert answer.get_json()["spec"] == {**body, "persist_every": None, "allow_anonymous": None, "mqtt_port": None, "users": [], "tls": False, "certificate_port": None, "kafka": None, "closed_kafkas": [], "tls_kafkas": []}  # optional, reported


def test_a_bad_id_in_the_url_is_refused(client: FlaskClient) -> None:
    response = put(client, "/v1/brokers/..", spec(broker_id=".."))
    assert response.status_code in (400, 404)
    response = client.get("/v1/brokers/a%20b", headers=AUTH)
    assert response.status_code == 400 and error(response)["field"] == "id"


@pytest.mark.parametrize("name", ["a\n", "\n", "a\nb", "a/\r\n"])
def test_a_topic_name_with_a_newline_reaches_its_route_and_is_refused(client: FlaskClient, name: str) -> None:
    """A name ending in a newline once matched no route: Flask's "URL not found" 404, which the
    OpenAPI document does not list for DELETE (found by the fuzzer). Every topic route now takes
    it: DELETE answers as for any absent topic (204, idempotent), PUT refuses the name (400)."""
    response = client.delete(url("m1", name), headers=AUTH)
    assert response.status_code == 204, response.get_json()
    response = client.put(url("m1", name), headers=AUTH, json={"name": name, "qos": 1})
    assert response.status_code == 400, response.get_json()


def test_an_unknown_kind_is_unprocessable(client: FlaskClient) -> None:
    response = put(client, url("m1"), spec(kind="activemq"))
    assert response.status_code == 422
    assert "no driver for broker kind 'activemq'" in error(response)["error"]


def test_kafka_on_a_wildcard_address_is_refused_before_anything_starts(client: FlaskClient) -> None:
    response = put(client, url("k1"), spec("k1", kind="kafka", host="0.0.0.0"))
    assert response.status_code == 400 and error(response)["field"] == "advertised_host"


def test_unknown_things(client: FlaskClient) -> None:
    assert client.get(url("nope"), headers=AUTH).status_code == 404
    assert client.delete(url("nope"), headers=AUTH).status_code == 204
    assert client.delete(url("nope", "a/b"), headers=AUTH).status_code == 204
    response = put(client, url("nope", "t"), topic("t", "nope"))
    assert response.status_code == 404 and "no broker 'nope'" in error(response)["error"]
    response = client.get("/v1/nothing", headers=AUTH)
    assert response.status_code == 404 and error(response)["hint"]
    response = client.post("/v1/brokers", headers=AUTH)
    assert response.status_code == 405 and error(response)["error"]


# --- a real Mosquitto ----------------------------------------------------------------------

def test_mosquitto_life_cycle(client: FlaskClient, state: AgentState, tmp_path: Path) -> None:
    body = spec()
    first = put(client, url("m1"), body)
    assert first.status_code == 200, first.get_json()
    running = first.get_json()
    assert running["status"] == "running" and running["restarts"] == 0
    assert running["spec"] == {**body, "persist_every": None, "allow_anonymous": None, "mqtt_port": None, "users": [],
                               "tls": False, "certificate_port": None, "kafka": None, "closed_kafkas": [], "tls_kafkas": []} and running["topics"] == []
    pid = running["pid"]
    assert proc_info(pid) is not None and netutil.port_open("127.0.0.1", body["port"])

    # Idempotent: same essence -> same process; a new name is recorded without a restart.
    assert put(client, url("m1"), body).get_json()["pid"] == pid
    renamed = put(client, url("m1"), {**body, "name": "Renamed"}).get_json()
    assert renamed["pid"] == pid and renamed["spec"]["name"] == "Renamed"
    folder = tmp_path / "state" / "brokers" / "m1"
    assert json.loads((folder / "spec.json").read_text())["name"] == "Renamed"
    assert json.loads((folder / "pid.json").read_text())["pid"] == pid

    # Topics of an MQTT broker are recorded (names with slashes survive the URL).
    name = "/cell//robot/position"
    answer = put(client, url("m1", name), topic(name, qos=1, retain=True))
    assert answer.status_code == 200, answer.get_json()
    assert answer.get_json() == {"name": name, "partitions": None, "replication_factor": None,
                                 "retention_ms": None, "qos": 1, "retain": True,
                                 "entity_id": None, "entity_type": None, "owner": None,
                                 "min_insync_replicas": None}
    assert put(client, url("m1", "other"), topic(name)).status_code == 400
    assert put(client, url("m1", name), topic(name, partitions=3)).status_code == 400
    assert put(client, url("m1", name), topic(name, broker_id="m2")).status_code == 400
    listed = client.get("/v1/brokers", headers=AUTH).get_json()["brokers"]
    assert [b["spec"]["id"] for b in listed] == ["m1"]
    assert [t["name"] for t in listed[0]["topics"]] == [name]
    assert client.delete(url("m1", name), headers=AUTH).status_code == 204
    assert client.get(url("m1"), headers=AUTH).get_json()["topics"] == []

    # A new port: restarted, the old port no longer answers.
    moved = put(client, url("m1"), {**body, "port": netutil.free_port()}).get_json()
    assert moved["pid"] != pid and moved["status"] == "running"
    assert proc_info(pid) is None
    assert not netutil.port_open("127.0.0.1", body["port"])
    assert moved["config_hash"] != running["config_hash"]

    # DELETE: process gone, folder retired (kept for a post-mortem), idempotent.
    assert client.delete(url("m1"), headers=AUTH).status_code == 204
    assert proc_info(moved["pid"]) is None
    assert not folder.exists()
    assert [p.name.split(".")[0] for p in (tmp_path / "state" / "removed").iterdir()] == ["m1"]
    assert client.delete(url("m1"), headers=AUTH).status_code == 204
    assert client.get(url("m1"), headers=AUTH).status_code == 404


def test_a_broker_that_cannot_start_is_failed_with_its_log(client: FlaskClient) -> None:
    with socket.create_server(("127.0.0.1", 0)) as taken:
        body = spec(port=taken.getsockname()[1])
        response = put(client, url("m1"), body)
        assert response.status_code == 422
        answer = error(response)
        assert "exited" in answer["error"] and "Address already in use" in answer["error"]
        assert answer["retryable"] is False
        observed = client.get(url("m1"), headers=AUTH).get_json()
        assert observed["status"] == "failed" and observed["pid"] is None
        assert "Address already in use" in observed["last_error"]
    # The port is free again: the same PUT now works.
    assert put(client, url("m1"), body).get_json()["status"] == "running"


def test_a_start_past_its_deadline_is_503_and_a_new_put_waits_for_it(tmp_path: Path) -> None:
    class NotYetHealthy(MosquittoDriver):
        """The real mosquitto, but its health check says no until the test allows it: a start
        that outlives its deadline, without depending on how fast the machine is."""

        allowed = threading.Event()

        def health(self, spec, timeout):  # type: ignore[no-untyped-def]
            return self.allowed.is_set() and super().health(spec, timeout)

    driver = NotYetHealthy()
    driver.start_deadline = 0.5
    manager = BrokerManager(tmp_path / "state", DriverRegistry([driver])).open()
    try:
        client = create_app(AgentState(manager, TOKEN)).test_client()
        body = spec()
        response = put(client, url("m1"), body)
        assert response.status_code == 503
        assert error(response)["retryable"] is True and "still starting" in error(response)["error"]
        driver.allowed.set()
        driver.start_deadline = 10.0
        again = put(client, url("m1"), body).get_json()
        assert again["status"] == "running" and again["restarts"] == 0
    finally:
        manager.close(stop_brokers=True)
    assert not processes_mentioning(tmp_path)


def test_mqtt_topics_are_recorded_even_while_the_broker_failed(client: FlaskClient) -> None:
    with socket.create_server(("127.0.0.1", 0)) as taken:
        put(client, url("m1"), spec(port=taken.getsockname()[1]))
    # MQTT topics are records: accepted even while the broker is failed.
    assert put(client, url("m1", "a"), topic("a")).status_code == 200
