"""A real RabbitMQ node deployed by the driver, as the agent deploys a broker: prepare, render,
spawn the command in a process group of its own, poll health with a deadline, stop the group.

Then: topics are real queues; Mosquitto's own bridge carries MQTT messages to the node's MQTT
port, where they wait in the topic's queue for an AMQP consumer; a stop keeps durable queues and
persistent messages; no process of the node survives its stop.
"""

from __future__ import annotations

import getpass
import os
import secrets
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import pytest

pytest.importorskip("plantkg_rabbitmq", reason="plugins/plantkg-rabbitmq is not installed (make setup)")

import pika
from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import mosquitto_runtime, netutil, parts, process
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
        return RabbitmqDriver.mqtt_port(self.broker_dir)


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


def processes_mentioning(text: str) -> list[str]:
    """Command lines of live processes that contain ``text``."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit() or int(entry.name) == os.getpid():
            continue
        try:
            cmdline = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            state = (entry / "stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if text in cmdline and state != "Z":
            found.append(f"{entry.name}: {cmdline}")
    return found


def stop_node(node: Node) -> None:
    process.stop(node.child, RabbitmqDriver.stop_grace)
    ports = config.read_ports(node.broker_dir)
    assert not node.child.group_alive()
    assert processes_mentioning(str(node.broker_dir)) == []
    assert processes_mentioning(f"-port {ports.epmd}") == []  # its own port mapper
    for port in (node.spec.port, ports.mqtt, ports.dist, ports.epmd):
        assert not netutil.port_open("127.0.0.1", port), f"port {port} still open"


@pytest.fixture(scope="module")
def node(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Node]:
    broker_dir = tmp_path_factory.mktemp("rabbitmq") / "brokers" / "amqp1"
    broker_dir.mkdir(parents=True)
    spec = BrokerSpec(id="amqp1", iri="urn:amqp1", name="cell-amqp", kind="rabbitmq",
                      host="127.0.0.1", port=netutil.free_port())
    running = start_node(RabbitmqDriver(), spec, broker_dir)
    print(f"RabbitMQ answered AMQP {running.ready_s:.1f} s after spawn")
    try:
        yield running
    finally:
        stop_node(running)


def get_message(spec: BrokerSpec, queue: str, deadline: float) -> tuple | None:
    """basic_get polled until a message arrives or ``deadline`` s pass: (method, props, body)."""
    with amqp.channel(spec.host, spec.port) as ch:
        def fetch():
            method, props, body = ch.basic_get(queue=queue, auto_ack=True)
            return (method, props, body) if method is not None else None
        try:
            return process.wait_until(fetch, deadline, 0.1, what=f"a message in queue {queue!r}")
        except Exception:  # noqa: BLE001 - the caller asserts
            return None


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
    port = netutil.free_port()
    bridge = mosquitto_runtime.MosquittoBridge(
        name="mqtt1-to-amqp1", remote_host="127.0.0.1", remote_port=node.mqtt_port,
        topics=(mosquitto_runtime.MosquittoBridgeTopic(TOPIC, "out", 1),),
        try_private=False)  # RabbitMQ refuses the bridge flag (protocol level 0x84) as corrupt
    cfg = mosquitto_runtime.MosquittoConfig(
        host="127.0.0.1", port=port, log_file=tmp_path / "mosquitto.log",
        run_as=getpass.getuser() if os.geteuid() == 0 else None, bridges=(bridge,))
    conf = tmp_path / "mosquitto.conf"
    conf.write_text(mosquitto_runtime.render_mosquitto_conf(cfg), encoding="utf-8")
    mosquitto = process.spawn(mosquitto_runtime.mosquitto_command(parts.mosquitto_binary(), conf),
                              log_dir=tmp_path, name="mosquitto-stdout")
    try:
        wait_bridge_connected(port, "mqtt1-to-amqp1", 20.0)
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


def test_a_stop_keeps_queues_and_persistent_messages(node: Node) -> None:
    """Runs last in the module: it restarts the node (ports and folder kept)."""
    RabbitmqDriver().ensure_topic(node.spec, TopicSpec(broker_id="amqp1", name="kept", iri="urn:k"))
    with amqp.channel(node.spec.host, node.spec.port) as ch:
        ch.confirm_delivery()
        ch.basic_publish(exchange="", routing_key="kept", body=b"survives",
                         properties=pika.BasicProperties(delivery_mode=2), mandatory=True)
    stop_node(node)
    again = start_node(RabbitmqDriver(), node.spec, node.broker_dir)
    node.child = again.child
    print(f"RabbitMQ answered AMQP {again.ready_s:.1f} s after a restart")
    got = get_message(node.spec, "kept", 10.0)
    assert got is not None and got[2] == b"survives"


def publish(port: int, topic: str, payload: bytes) -> None:
    """One QoS 1 publish to Mosquitto, waited for (PUBACK)."""
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"pub-{secrets.token_hex(4)}")
    client.connect("127.0.0.1", port)
    client.loop_start()
    try:
        client.publish(topic, payload, qos=1).wait_for_publish(timeout=10)
    finally:
        client.disconnect()
        client.loop_stop()


def wait_bridge_connected(port: int, name: str, deadline: float) -> None:
    """Mosquitto's retained bridge state notification says 1 (connected) within ``deadline``."""
    state: list[bytes] = []
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"state-{secrets.token_hex(4)}")
    client.on_message = lambda _c, _u, msg: state.append(msg.payload)
    process.wait_until(lambda: netutil.port_open("127.0.0.1", port), 10.0, what="Mosquitto")
    client.connect("127.0.0.1", port)
    client.subscribe(mosquitto_runtime.bridge_state_topic(name), qos=1)
    client.loop_start()
    try:
        process.wait_until(lambda: state and state[-1] == b"1", deadline, 0.05,
                           what=f"bridge {name} to connect to RabbitMQ's MQTT port")
    finally:
        client.disconnect()
        client.loop_stop()
