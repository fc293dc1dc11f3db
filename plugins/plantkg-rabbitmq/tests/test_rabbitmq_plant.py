"""A RabbitMQ broker deployed from a plant: ``plantkg apply`` against a real ``plantkg agent``, which
finds the driver through its entry point; the topic becomes a queue; a Mosquitto bridge into the
node's MQTT port fills it; ``plantkg destroy`` stops the node with nothing left behind.

The plant-level bridge (``pk:bridgesTo`` between a Mosquitto and a RabbitMQ broker) is not derived
yet: the Mosquitto here is the test's own, with Mosquitto's bridge to the node's MQTT port.
"""

from __future__ import annotations

import re
import secrets
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

pytest.importorskip("plantkg_rabbitmq", reason="plugins/plantkg-rabbitmq is not installed (make setup)")

from rabbitmq_test_helpers import get_message, processes_mentioning, publish, start_bridging_mosquitto

from engine import netutil, process
from engine.agent.local import LocalAgents, start_local_agents
from engine.cli import main
from plantkg_rabbitmq import amqp, config
from plantkg_rabbitmq.driver import RabbitmqDriver

pytestmark = pytest.mark.integration

PLANT = Path(__file__).resolve().parent / "plants" / "rabbitmq-cell.ttl"
HOST = "127.0.0.1"
TOPIC = "cell/pose"


@dataclass
class Deployment:
    agents: LocalAgents
    plant: Path
    port: int
    tmp: Path

    def broker_dir(self) -> Path:
        return self.agents.agents[HOST].state_dir / "brokers" / "amqp1"


@pytest.fixture(scope="module")
def deployment(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployment]:
    tmp = tmp_path_factory.mktemp("rabbitmq-plant")
    port = netutil.free_port(HOST)
    plant = tmp / "plant.ttl"
    plant.write_text(re.sub(r"pk:port \d+", f"pk:port {port}", PLANT.read_text()), encoding="utf-8")
    agents = start_local_agents([HOST], tmp)
    try:
        yield Deployment(agents, plant, port, tmp)
    finally:
        try:
            agents.delete_all()  # a safety net: test_destroy... removes the broker itself
        finally:
            agents.stop()


def run(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str]:
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out + out.err


def test_apply_deploys_the_node_and_its_queue(deployment: Deployment, capsys) -> None:
    code, out = run(capsys, "apply", deployment.plant, "--agents", deployment.agents.agents_file, "--yes")
    assert code == 0, out
    [broker] = deployment.agents.agents[HOST].client().list_brokers()
    assert broker.spec.kind == "rabbitmq" and broker.status.value == "running", broker
    assert amqp.queue_exists(HOST, deployment.port, TOPIC)
    code, out = run(capsys, "plan", deployment.plant, "--agents", deployment.agents.agents_file)
    assert code == 0 and "No changes" in out, out


def test_a_mosquitto_bridge_fills_the_deployed_queue(deployment: Deployment, tmp_path: Path) -> None:
    mqtt_port = RabbitmqDriver.mqtt_port(deployment.broker_dir())
    mosquitto, port = start_bridging_mosquitto(tmp_path, mqtt_port, TOPIC, "mqtt-to-amqp1")
    try:
        payload = f"pose {secrets.token_hex(4)}".encode()
        publish(port, TOPIC, payload)
        spec = deployment.agents.agents[HOST].client().list_brokers()[0].spec
        got = get_message(spec, TOPIC, 20.0)
        assert got is not None and got[2] == payload
    finally:
        process.stop(mosquitto, 5.0)


def test_destroy_stops_the_node_and_leaves_nothing(deployment: Deployment, capsys) -> None:
    broker_dir = deployment.broker_dir()
    ports = config.read_ports(broker_dir)
    code, out = run(capsys, "destroy", deployment.plant, "--agents", deployment.agents.agents_file, "--yes")
    assert code == 0, out
    assert deployment.agents.agents[HOST].client().list_brokers() == []
    assert processes_mentioning(str(broker_dir)) == []
    for port in (deployment.port, ports.mqtt, ports.dist, ports.epmd):
        assert not netutil.port_open(HOST, port), f"port {port} still open"
