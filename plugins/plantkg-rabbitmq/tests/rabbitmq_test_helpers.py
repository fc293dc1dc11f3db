"""Helpers of the RabbitMQ plugin's integration tests: a bridging Mosquitto, MQTT publish, AMQP
get, and the check that no process of a stopped node is left."""

from __future__ import annotations

import getpass
import os
import secrets
from pathlib import Path

from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import netutil, parts, process
from engine.drivers.mosquitto import runtime as mosquitto_runtime
from engine.model import BrokerSpec
from plantkg_rabbitmq import amqp


def start_bridging_mosquitto(tmp_path: Path, mqtt_port: int, topic: str, name: str) -> tuple[process.Child, int]:
    """A Mosquitto of the test's own whose bridge ``name`` sends ``topic`` (QoS 1) to a RabbitMQ
    node's MQTT port; returns the child and Mosquitto's port once the bridge is connected."""
    port = netutil.free_port()
    bridge = mosquitto_runtime.MosquittoBridge(
        name=name, remote_host="127.0.0.1", remote_port=mqtt_port,
        topics=(mosquitto_runtime.MosquittoBridgeTopic(topic, "out", 1),),
        try_private=False)  # RabbitMQ refuses the bridge flag (protocol level 0x84) as corrupt
    cfg = mosquitto_runtime.MosquittoConfig(
        host="127.0.0.1", port=port, log_file=tmp_path / "mosquitto.log",
        run_as=getpass.getuser() if os.geteuid() == 0 else None, bridges=(bridge,))
    conf = tmp_path / "mosquitto.conf"
    conf.write_text(mosquitto_runtime.render_mosquitto_conf(cfg), encoding="utf-8")
    child = process.spawn(mosquitto_runtime.mosquitto_command(parts.mosquitto_binary(), conf),
                          log_dir=tmp_path, name="mosquitto-stdout")
    try:
        wait_bridge_connected(port, name, 20.0)
    except BaseException:
        process.stop(child, 5.0)
        raise
    return child, port


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
