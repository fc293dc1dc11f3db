"""A real RabbitMQ node deployed by the driver, as the agent deploys a broker: prepare, render,
spawn the command in a process group of its own, poll health with a deadline, stop the group.

Then: topics are real queues; Mosquitto's own bridge carries MQTT messages to the node's MQTT
port, where they wait in the topic's queue for an AMQP consumer; a stop keeps durable queues and
persistent messages; no process of the node survives its stop.
"""

from __future__ import annotations

import os
import secrets
import signal
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import pytest

pytest.importorskip("plantkg_rabbitmq", reason="plugins/plantkg-rabbitmq is not installed (make setup)")

import pika
from rabbitmq_test_helpers import get_message, processes_mentioning, publish, start_bridging_mosquitto

from engine import netutil, process
from engine.drivers.base import log_file
from engine.model import BrokerSpec, TopicSpec
from plantkg_rabbitmq import amqp, config
from plantkg_rabbitmq.driver import RabbitmqDriver

pytestmark = pytest.mark.integration

TOPIC = "cell/robot.pose"


@dataclass
class Node:
    spec: BrokerSpec
    broker_dir: Path
    child: process.Child
    ready_s: float

    @property
    def mqtt_port(self) -> int:
        assert self.spec.mqtt_port is not None
        return self.spec.mqtt_port


def start_node(driver: RabbitmqDriver, spec: BrokerSpec, broker_dir: Path) -> Node:
    """What the agent does on start: validate, prepare, render, spawn, poll health."""
    driver.validate(spec)
    driver.prepare(spec, broker_dir)
    for name, text in driver.render_config(spec, broker_dir).items():
        (broker_dir / name).write_text(text, encoding="utf-8")
    log = log_file(broker_dir, driver.kind)
    began = time.monotonic()
    child = process.spawn(driver.command(spec, broker_dir), log_dir=log.parent, name=driver.kind,
                          cwd=broker_dir)
    try:
        process.wait_until(lambda: driver.health(spec, 1.0), driver.start_deadline, 0.2,
                           what=f"RabbitMQ to answer AMQP on {spec.host}:{spec.port}", child=child)
    except BaseException:
        process.stop(child, driver.stop_grace)
        raise
    return Node(spec, broker_dir, child, time.monotonic() - began)


def stop_node(node: Node) -> None:
    process.stop(node.child, RabbitmqDriver.stop_grace)
    ports = config.read_ports(node.broker_dir)
    assert not node.child.group_alive()
    assert processes_mentioning(str(node.broker_dir)) == []
    assert processes_mentioning(f"-port {ports.epmd}") == []  # its own port mapper
    # The listeners close as the killed VM's last threads finish exiting, which can be a moment
    # after its group is gone from /proc: poll, with a deadline, rather than look once.
    for port in (node.spec.port, node.mqtt_port, ports.dist, ports.epmd):
        process.wait_until(lambda p=port: not netutil.port_open("127.0.0.1", p), 10.0, 0.05,
                           what=f"port {port} of the stopped node to close")


@pytest.fixture(scope="module")
def node(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Node]:
    broker_dir = tmp_path_factory.mktemp("rabbitmq") / "brokers" / "amqp1"
    broker_dir.mkdir(parents=True)
    amqp_port, mqtt_port = netutil.free_ports(2, "127.0.0.1")
    spec = BrokerSpec(id="amqp1", iri="urn:amqp1", name="cell-amqp", kind="rabbitmq",
                      host="127.0.0.1", port=amqp_port, mqtt_port=mqtt_port)
    running = start_node(RabbitmqDriver(), spec, broker_dir)
    print(f"RabbitMQ answered AMQP {running.ready_s:.1f} s after spawn")
    try:
        yield running
    finally:
        stop_node(running)


def test_topics_are_durable_queues(node: Node) -> None:
    driver = RabbitmqDriver()
    topic = TopicSpec(broker_id="amqp1", name="cell/temp", iri="urn:t")
    assert driver.ensure_topic(node.spec, topic).name == "cell/temp"
    assert driver.ensure_topic(node.spec, topic).name == "cell/temp"  # idempotent
    assert amqp.queue_exists(node.spec.host, node.spec.port, "cell/temp")
    driver.delete_topic(node.spec, "cell/temp")
    assert not amqp.queue_exists(node.spec.host, node.spec.port, "cell/temp")
    driver.delete_topic(node.spec, "cell/temp")  # absent: nothing to do


def test_health_speaks_amqp(node: Node) -> None:
    assert RabbitmqDriver().health(node.spec, 2.0)
    # The MQTT port is open but is no AMQP listener: health must not pass there.
    assert not RabbitmqDriver().health(replace(node.spec, port=node.mqtt_port), 1.0)


def test_mosquitto_bridges_mqtt_into_a_rabbitmq_queue(node: Node, tmp_path: Path) -> None:
    RabbitmqDriver().ensure_topic(node.spec, TopicSpec(broker_id="amqp1", name=TOPIC, iri="urn:t"))
    mosquitto, port = start_bridging_mosquitto(tmp_path, node.mqtt_port, TOPIC, "mqtt1-to-amqp1")
    try:
        payload = f"pose {secrets.token_hex(4)}".encode()
        publish(port, TOPIC, payload)
        got = get_message(node.spec, TOPIC, 20.0)
        assert got is not None, (tmp_path / "mosquitto.log").read_text()[-2000:]
        method, props, body = got
        assert body == payload
        assert method.routing_key == amqp.routing_key(TOPIC) == "cell.robot.pose"
        assert props.delivery_mode == 2  # QoS 1 arrives persistent
    finally:
        process.stop(mosquitto, 5.0)


def publish_confirmed(spec: BrokerSpec, queue: str, body: bytes) -> None:
    """A persistent AMQP publish the node confirmed (it is on disk then)."""
    with amqp.channel(spec.host, spec.port) as ch:
        ch.confirm_delivery()
        ch.basic_publish(exchange="", routing_key=queue, body=body,
                         properties=pika.BasicProperties(delivery_mode=2), mandatory=True)


def test_a_stop_keeps_queues_and_persistent_messages(node: Node) -> None:
    """Restarts the node (ports and folder kept); the tests after it use the new node."""
    RabbitmqDriver().ensure_topic(node.spec, TopicSpec(broker_id="amqp1", name="kept", iri="urn:k"))
    publish_confirmed(node.spec, "kept", b"survives a stop")
    stop_node(node)
    again = start_node(RabbitmqDriver(), node.spec, node.broker_dir)
    node.child = again.child
    print(f"RabbitMQ answered AMQP {again.ready_s:.1f} s after a restart")
    got = get_message(node.spec, "kept", 10.0)
    assert got is not None and got[2] == b"survives a stop"


def test_kill_9_loses_no_confirmed_message(node: Node) -> None:
    """Safe by default: a confirmed persistent message survives SIGKILL of the node's group."""
    RabbitmqDriver().ensure_topic(node.spec, TopicSpec(broker_id="amqp1", name="kept", iri="urn:k"))
    publish_confirmed(node.spec, "kept", b"survives kill -9")
    os.killpg(node.child.pid, signal.SIGKILL)
    stop_node(node)  # reaps, and checks that nothing of the node is left
    again = start_node(RabbitmqDriver(), node.spec, node.broker_dir)
    node.child = again.child
    print(f"RabbitMQ answered AMQP {again.ready_s:.1f} s after kill -9")
    got = get_message(node.spec, "kept", 10.0)
    assert got is not None and got[2] == b"survives kill -9"
