"""The engine and agent sides of an mqtt-ngsi bridge: the worker config the agent builds from a
BridgeSpec, and the context broker's token travelling from the engine's agents file to the
carrying agent as a transport field (never in a plan, an operation, a spec or an answer)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import pytest
from flask.testing import FlaskClient

from engine.agent.app import AgentState, create_app
from engine.agent.client import AgentClient
from engine.agent.workers import WorkerManager, _config_text, ngsi_worker_config
from engine.agents_config import AgentDirectory, AgentEntry
from engine.apply import apply, operations
from engine.bridge_worker.ngsi_config import NgsiDirection
from engine.errors import ConfigValueError
from engine.model import (
    Action,
    BridgeDirection,
    BridgeEnd,
    BridgeMechanism,
    BridgeRoute,
    BridgeSpec,
    BridgeStatus,
    Change,
    DesiredState,
    ObservedBridge,
    ObservedState,
    Plan,
    to_dict,
)

MQTT = BridgeEnd("mqtt", "mosquitto", "127.0.0.2", 1883)
ORION = BridgeEnd("orion", "ngsi-v2", "127.0.0.5", 1026)


def ngsi_spec(*routes: BridgeRoute) -> BridgeSpec:
    routes = routes or (BridgeRoute("agv/7/state", BridgeDirection.BOTH, 2,
                                    entity_id="urn:ngsi-ld:AGV:7", entity_type="AGV"),)
    return BridgeSpec(MQTT, ORION, BridgeMechanism.NGSI, routes)


# --- the worker config the agent writes ---------------------------------------------------------

def test_each_direction_of_a_route_is_one_worker_route(tmp_path: Path) -> None:
    cfg = ngsi_worker_config(ngsi_spec(), tmp_path, tmp_path / "remote.token")
    assert cfg.bridge_id == "mqtt--orion"
    assert (cfg.mqtt_host, cfg.mqtt_port, cfg.ngsi_url) == ("127.0.0.2", 1883, "http://127.0.0.5:1026")
    assert [(r.mqtt_topic, r.entity_id, r.entity_type, r.direction, r.qos) for r in cfg.routes] == [
        ("agv/7/state", "urn:ngsi-ld:AGV:7", "AGV", NgsiDirection.MQTT_TO_NGSI, 1),  # QoS 2 -> 1
        ("agv/7/state", "urn:ngsi-ld:AGV:7", "AGV", NgsiDirection.NGSI_TO_MQTT, 1),
    ]
    assert cfg.token_file == tmp_path / "remote.token"


def test_a_route_without_its_entity_is_refused_naming_it(tmp_path: Path) -> None:
    spec = ngsi_spec(BridgeRoute("a", BridgeDirection.OUT, entity_id="urn:a", entity_type="T"),
                     BridgeRoute("b", BridgeDirection.IN))
    with pytest.raises(ConfigValueError) as exc:
        ngsi_worker_config(spec, tmp_path, None)
    assert exc.value.field == "routes[1].entity_id"


def test_ipv6_context_broker_url_is_bracketed(tmp_path: Path) -> None:
    spec = BridgeSpec(MQTT, BridgeEnd("orion", "ngsi-v2", "::1", 1026), BridgeMechanism.NGSI,
                      ngsi_spec().routes)
    assert ngsi_worker_config(spec, tmp_path, None).ngsi_url == "http://[::1]:1026"


def test_a_tls_context_broker_is_reached_over_https_verified_by_the_plant_ca(tmp_path: Path) -> None:
    from engine.security import ca  # noqa: PLC0415
    plain = ngsi_worker_config(ngsi_spec(), tmp_path, None)
    assert (plain.ngsi_url, plain.ngsi_ca_file) == ("http://127.0.0.5:1026", None)
    spec = replace(ngsi_spec(), remote=replace(ORION, tls=True))
    cfg = ngsi_worker_config(spec, tmp_path, None)
    assert (cfg.ngsi_url, cfg.ngsi_ca_file) == ("https://127.0.0.5:1026", ca.ca_cert_file())


def test_only_an_ngsi_worker_takes_a_remote_token(tmp_path: Path) -> None:
    mirror = BridgeSpec(BridgeEnd("k2", "kafka", "127.0.0.4", 9092), BridgeEnd("kafka", "kafka", "127.0.0.3", 9092),
                        BridgeMechanism.MIRROR, (BridgeRoute("t", BridgeDirection.IN),))
    kafka = BridgeSpec(MQTT, BridgeEnd("kafka", "kafka", "127.0.0.3", 9092, closed=True), BridgeMechanism.WORKER,
                       (BridgeRoute("t", BridgeDirection.OUT),))
    for spec in (mirror, kafka):
        with pytest.raises(ConfigValueError) as exc:
            _config_text(spec, tmp_path, "secret")
        assert exc.value.field == "remote_token" and "secret" not in str(exc.value)
    # into a closed Kafka: the worker reads plantkg's password from a file, never from worker.json
    assert json.loads(_config_text(kafka, tmp_path, None))["kafka_password_file"] == str(tmp_path / "remote.token")
    opened = replace(kafka, remote=replace(kafka.remote, closed=False))
    assert "kafka_password_file" not in json.loads(_config_text(opened, tmp_path, None))
    open_cb = json.loads(_config_text(ngsi_spec(), tmp_path, None))
    assert open_cb["token_file"] is None
    with_token = json.loads(_config_text(ngsi_spec(), tmp_path, "secret"))
    assert with_token["token_file"] == str(tmp_path / "remote.token") and "secret" not in json.dumps(with_token)


# --- the agent's PUT ------------------------------------------------------------------------------

@dataclass
class RecordingWorkers(WorkerManager):
    """A WorkerManager that records what put() was given instead of starting a process."""

    state_dir: Path = Path("/nonexistent")
    got: list[tuple[BridgeSpec, str | None]] = field(default_factory=list)

    def put(self, spec: BridgeSpec, remote_token: str | None = None) -> ObservedBridge:  # type: ignore[override]
        self.got.append((spec, remote_token))
        return ObservedBridge(spec, BridgeStatus.CONNECTING)


class Brokers:
    """Just enough of a BrokerManager for the bridge PUT: the local broker exists here."""

    class _Observed:
        def __init__(self) -> None:
            self.spec = MQTT

    def get(self, broker_id: str) -> object:
        return self._Observed() if broker_id == "mqtt" else None


@pytest.fixture
def recording(tmp_path: Path) -> RecordingWorkers:
    return RecordingWorkers(state_dir=tmp_path)


@pytest.fixture
def client(recording: RecordingWorkers) -> FlaskClient:
    app = create_app(AgentState(brokers=Brokers(), token="agent-token", workers=recording))  # type: ignore[arg-type]
    return app.test_client()


AUTH = {"Authorization": "Bearer agent-token"}


def test_put_hands_the_token_to_the_worker_and_never_answers_it(client: FlaskClient,
                                                                recording: RecordingWorkers) -> None:
    body = {**to_dict(ngsi_spec()), "remote_token": "cb-secret"}
    answer = client.put("/v1/brokers/mqtt/bridges/orion", json=body, headers=AUTH)
    assert answer.status_code == 200, answer.get_json()
    assert recording.got == [(ngsi_spec(), "cb-secret")]
    assert "cb-secret" not in answer.get_data(as_text=True)
    plain = client.put("/v1/brokers/mqtt/bridges/orion", json=to_dict(ngsi_spec()), headers=AUTH)
    assert plain.status_code == 200 and recording.got[-1] == (ngsi_spec(), None)


@pytest.mark.parametrize(("token", "problem"), [("", "non-empty"), (7, "non-empty"), ("a\nb", "printable")])
def test_a_bad_remote_token_is_a_400_naming_the_field(client: FlaskClient, recording: RecordingWorkers,
                                                      token: object, problem: str) -> None:
    answer = client.put("/v1/brokers/mqtt/bridges/orion", json={**to_dict(ngsi_spec()), "remote_token": token},
                        headers=AUTH)
    assert answer.status_code == 400
    assert answer.get_json()["field"] == "remote_token" and problem in answer.get_json()["error"]
    assert recording.got == []


def test_a_remote_token_on_a_mosquitto_bridge_is_a_400(client: FlaskClient, recording: RecordingWorkers) -> None:
    other = BridgeSpec(MQTT, BridgeEnd("m2", "mosquitto", "127.0.0.3", 1883), BridgeMechanism.MOSQUITTO,
                       (BridgeRoute("t", BridgeDirection.OUT),))
    answer = client.put("/v1/brokers/mqtt/bridges/m2", json={**to_dict(other), "remote_token": "x"},
                        headers=AUTH)
    assert answer.status_code == 400 and answer.get_json()["field"] == "remote_token"
    assert recording.got == []


# --- the engine's side: apply looks the token up only when it calls ------------------------------

class FakeAgent:
    def __init__(self, url: str, token: str, calls: list) -> None:
        self.url, self.token, self.calls = url, token, calls

    def put_bridge(self, spec: BridgeSpec, remote_token: str | None = None) -> None:
        self.calls.append((self.url, self.token, spec.address, remote_token))


def run_apply(entries: dict[str, AgentEntry], default_token: str | None = None) -> list:
    spec = ngsi_spec()
    plan = Plan((Change(spec.address, Action.CREATE, None, to_dict(spec)),))
    calls: list = []
    directory = AgentDirectory(entries=entries, default_token=default_token,
                               client_factory=lambda url, token: FakeAgent(url, token, calls))  # type: ignore[arg-type,return-value]
    result = apply(plan, DesiredState(bridges=(spec,)), directory,
                   observe_fn=lambda _d, _h: ObservedState(), sleep=lambda _s: None)
    assert result.outcomes[0].status.value == "done", result.outcomes
    return calls


def test_apply_sends_the_context_broker_agents_token_with_the_put() -> None:
    entries = {"127.0.0.2": AgentEntry("127.0.0.2", "http://127.0.0.2:7300", token="mqtt-agent"),
               "127.0.0.5": AgentEntry("127.0.0.5", "http://127.0.0.5:7300", token="cb-agent")}
    assert run_apply(entries) == [("http://127.0.0.2:7300", "mqtt-agent", "bridge.mqtt.orion", "cb-agent")]


def test_apply_sends_no_token_when_the_context_brokers_agent_is_unknown() -> None:
    entries = {"127.0.0.2": AgentEntry("127.0.0.2", "http://127.0.0.2:7300", token="mqtt-agent")}
    assert run_apply(entries) == [("http://127.0.0.2:7300", "mqtt-agent", "bridge.mqtt.orion", None)]


def test_no_token_is_part_of_the_operations() -> None:
    spec = ngsi_spec()
    ops = operations(Plan((Change(spec.address, Action.CREATE, None, to_dict(spec)),)),
                     DesiredState(bridges=(spec,)))
    [call] = ops[0].calls
    assert (call.verb, call.host, call.args, call.remote_token_of) == ("put_bridge", "127.0.0.2", (spec,), "127.0.0.5")


def test_the_client_sends_the_token_beside_the_spec(monkeypatch: pytest.MonkeyPatch) -> None:
    sent: list = []
    client = AgentClient("http://127.0.0.2:7300", "agent-token")

    def request(method: str, path: str, body: object = None, **_: object) -> object:
        sent.append(body)
        return to_dict(ObservedBridge(ngsi_spec(), BridgeStatus.RUNNING))

    monkeypatch.setattr(client, "_request", request)
    client.put_bridge(ngsi_spec(), remote_token="cb-secret")
    client.put_bridge(ngsi_spec())
    assert sent == [{**to_dict(ngsi_spec()), "remote_token": "cb-secret"}, to_dict(ngsi_spec())]


def test_status_shows_what_the_remote_refused_while_running() -> None:
    from engine.cli.status import bridge_rows

    spec = ngsi_spec()
    seen = ObservedBridge(spec, BridgeStatus.RUNNING, forwarded=10, retried=0, refused=3,
                          last_error="message on 'agv/7/state' refused ...")
    [row] = bridge_rows(DesiredState(bridges=(spec,)), ObservedState(bridges=(seen,)))
    assert (row["forwarded"], row["retried"], row["error"]) == ("10", "0", "3 refused by the remote")
    [quiet] = bridge_rows(DesiredState(bridges=(spec,)),
                          ObservedState(bridges=(ObservedBridge(spec, BridgeStatus.RUNNING, refused=0),)))
    assert quiet["error"] == ""
