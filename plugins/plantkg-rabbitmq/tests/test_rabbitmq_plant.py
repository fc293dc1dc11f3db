"""RabbitMQ brokers deployed from plants, with real agents: ``plantkg apply`` finds the driver
through its entry point and the topic becomes a queue; in a plant where a robot publishes on a
Mosquitto and a warehouse system subscribes on RabbitMQ, rule R1 derives the bridge (the plugin's
ontology makes a RabbitMQ broker a pk:MqttBroker) and the Mosquitto's agent runs it to the node's
``pk:mqttPort``: a message published on Mosquitto is read from the queue over AMQP. ``plantkg
destroy`` stops everything with no process or port left behind.
"""

from __future__ import annotations

import re
import secrets
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

pytest.importorskip("plantkg_rabbitmq", reason="plugins/plantkg-rabbitmq is not installed (make setup)")

from rabbitmq_test_helpers import get_message, processes_mentioning, publish, wait_bridge_connected

from engine import netutil
from engine.agent.local import LocalAgents, start_local_agents
from engine.cli import main
from plantkg_rabbitmq import amqp, config

pytestmark = pytest.mark.integration

PLANTS = Path(__file__).resolve().parent / "plants"
HOST = "127.0.0.1"
TOPIC = "cell/pose"


@dataclass
class Deployment:
    agents: LocalAgents
    plant: Path
    ports: dict[str, int]   # pk:port / pk:mqttPort value in the shipped plant -> the free one used

    def broker_dir(self, broker_id: str = "amqp1") -> Path:
        return self.agents.agents[HOST].state_dir / "brokers" / broker_id


def with_free_ports(text: str) -> tuple[str, dict[str, int]]:
    found = re.findall(r"pk:(?:mqttPort|port) (\d+)", text)
    free = dict(zip(found, netutil.free_ports(len(found), HOST)))
    return re.sub(r"(pk:(?:mqttPort|port)) (\d+)", lambda m: f"{m[1]} {free[m[2]]}", text), \
        {k: v for k, v in free.items()}


def deploy(tmp: Path, name: str) -> Deployment:
    text, ports = with_free_ports((PLANTS / name).read_text())
    plant = tmp / name
    plant.write_text(text, encoding="utf-8")
    return Deployment(start_local_agents([HOST], tmp), plant, ports)


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployment]:
    deployment = deploy(tmp_path_factory.mktemp("rabbitmq-cell"), "rabbitmq-cell.ttl")
    try:
        yield deployment
    finally:
        try:
            deployment.agents.delete_all()  # a safety net: the destroy test removes the broker itself
        finally:
            deployment.agents.stop()


@pytest.fixture(scope="module")
def bridged(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployment]:
    deployment = deploy(tmp_path_factory.mktemp("mosquitto-to-rabbitmq"), "mosquitto-to-rabbitmq.ttl")
    try:
        yield deployment
    finally:
        try:
            deployment.agents.delete_all()
        finally:
            deployment.agents.stop()


def run(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str]:
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out + out.err


def test_apply_deploys_the_node_and_its_queue(cell: Deployment, capsys) -> None:
    code, out = run(capsys, "apply", cell.plant, "--agents", cell.agents.agents_file, "--yes")
    assert code == 0, out
    [broker] = cell.agents.agents[HOST].client().list_brokers()
    assert broker.spec.kind == "rabbitmq" and broker.status.value == "running", broker
    assert broker.spec.mqtt_port == cell.ports["1884"]
    assert amqp.queue_exists(HOST, cell.ports["5672"], TOPIC)
    code, out = run(capsys, "plan", cell.plant, "--agents", cell.agents.agents_file)
    assert code == 0 and "No changes" in out, out


def test_destroy_stops_the_node_and_leaves_nothing(cell: Deployment, capsys) -> None:
    broker_dir = cell.broker_dir()
    ports = config.read_ports(broker_dir)
    code, out = run(capsys, "destroy", cell.plant, "--agents", cell.agents.agents_file, "--yes")
    assert code == 0, out
    assert cell.agents.agents[HOST].client().list_brokers() == []
    assert processes_mentioning(str(broker_dir)) == []
    for port in (*cell.ports.values(), ports.dist, ports.epmd):
        assert not netutil.port_open(HOST, port), f"port {port} still open"


def test_the_plan_derives_a_mosquitto_bridge_to_the_mqtt_port(bridged: Deployment, capsys) -> None:
    code, out = run(capsys, "plan", bridged.plant, "--agents", bridged.agents.agents_file, "--format", "json")
    assert code == 0, out
    bridge = "bridge.floor.amqp1"
    assert bridge in out and f'"port": {bridged.ports["1884"]}' in out, out
    code, out = run(capsys, "explain", bridged.plant, bridge)
    assert code == 0 and "R1" in out and "Robot" in out and "Warehouse system" in out, out


def test_a_message_published_on_mosquitto_reaches_the_queue(bridged: Deployment, capsys) -> None:
    code, out = run(capsys, "apply", bridged.plant, "--agents", bridged.agents.agents_file, "--yes")
    assert code == 0, out
    mosquitto_port = bridged.ports["1883"]
    wait_bridge_connected(mosquitto_port, "plantkg.floor.amqp1", 30.0)
    payload = f"pose {secrets.token_hex(4)}".encode()
    publish(mosquitto_port, TOPIC, payload)
    spec = next(b.spec for b in bridged.agents.agents[HOST].client().list_brokers() if b.spec.id == "amqp1")
    got = get_message(spec, TOPIC, 20.0)
    assert got is not None and got[2] == payload
    code, out = run(capsys, "plan", bridged.plant, "--agents", bridged.agents.agents_file)
    assert code == 0 and "No changes" in out, out


def test_destroy_removes_the_bridge_and_both_brokers(bridged: Deployment, capsys) -> None:
    ports = config.read_ports(bridged.broker_dir())
    code, out = run(capsys, "destroy", bridged.plant, "--agents", bridged.agents.agents_file, "--yes")
    assert code == 0, out
    assert bridged.agents.agents[HOST].client().list_brokers() == []
    for broker_id in ("amqp1", "floor"):
        assert processes_mentioning(str(bridged.broker_dir(broker_id))) == []
    for port in (*bridged.ports.values(), ports.dist, ports.epmd):
        assert not netutil.port_open(HOST, port), f"port {port} still open"
