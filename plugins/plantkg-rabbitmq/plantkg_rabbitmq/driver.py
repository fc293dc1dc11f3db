"""The RabbitMQ driver: one node per broker folder, AMQP on the broker's port, MQTT beside it.

Implements plantkg's driver Protocol (``engine.drivers.base.Driver``; docs/drivers.md):

- *prepare* picks the node's MQTT, distribution and port-mapper ports once (``ports.json``) and
  makes the data folder; *render_config* writes ``rabbitmq.conf``, ``enabled_plugins`` (the MQTT
  plugin), an empty ``rabbitmq-env.conf`` and ``launch.json`` (:mod:`plantkg_rabbitmq.config`);
- *command* is :mod:`plantkg_rabbitmq.launch`, which runs the node's own port mapper and
  ``rabbitmq-server`` in the foreground, in the agent's process group;
- *health* opens a real AMQP connection (the AMQP listener starts after the MQTT one);
- topics are durable queues bound to ``amq.topic`` (:mod:`plantkg_rabbitmq.amqp`), so messages
  that arrive over MQTT wait for AMQP consumers. AMQP 0-9-1 cannot list queues, so the agent keeps
  the record of topics, as for MQTT (``implicit_topics``); the queues themselves are real.

The node is managed as ``guest``, whom RabbitMQ lets in over loopback only: the broker's address
must be a loopback address (127.0.0.0/8) for now.
"""

from __future__ import annotations

import ipaddress
import sys
from pathlib import Path
from typing import Any

from engine.drivers.base import (
    DATA_DIR,
    MQTT_TOPIC_FIELDS,
    check_text,
    check_topic_fields,
    refuse_bridges,
    spec_essence,
)
from engine.errors import ConfigValueError
from engine.model import BridgeSpec, BrokerSpec, ObservedTopic, TopicSpec
from plantkg_rabbitmq import amqp, config

#: AMQP 0-9-1: a queue name is a short string, at most 255 bytes.
MAX_QUEUE_NAME_BYTES = 255


class RabbitmqDriver:
    """RabbitMQ 3.x from the Debian package ``rabbitmq-server``."""

    kind = "rabbitmq"
    implicit_topics = True
    start_deadline = 90.0   # a first boot took 12-20 s here (Mnesia created), a restart 7-9 s
    stop_grace = 20.0

    def validate(self, spec: BrokerSpec) -> None:
        host = config.check_node_host(spec.host)
        if not ipaddress.ip_address(host).is_loopback:
            raise ConfigValueError("host", spec.host, "the rabbitmq driver manages its node as "
                                   "guest, whom RabbitMQ admits over loopback only; give the broker "
                                   "a 127.x.x.x address")
        config.render_files(host, spec.port, self._mqtt_port(spec), Path("/nonexistent/plantkg/broker"),
                            config.NodePorts(dist=3, epmd=4))

    def render_config(self, spec: BrokerSpec, broker_dir: Path,
                      bridges: tuple[BridgeSpec, ...] = ()) -> dict[str, str]:
        refuse_bridges(self.kind, bridges)
        self.validate(spec)
        return config.render_files(spec.host, spec.port, self._mqtt_port(spec), broker_dir,
                                   config.read_ports(broker_dir))

    def command(self, spec: BrokerSpec, broker_dir: Path) -> list[str]:
        config.server_binary()  # a missing install is reported here, not in the node's log
        config.epmd_binary()
        return [sys.executable, "-m", "plantkg_rabbitmq.launch", str(broker_dir)]

    def prepare(self, spec: BrokerSpec, broker_dir: Path) -> None:
        config.ensure_ports(broker_dir, config.check_node_host(spec.host))
        (broker_dir / DATA_DIR).mkdir(parents=True, exist_ok=True)

    def health(self, spec: BrokerSpec, timeout: float) -> bool:
        try:
            return amqp.answers(spec.host, spec.port, timeout)
        except Exception:  # noqa: BLE001 - health never raises
            return False

    def ensure_topic(self, spec: BrokerSpec, topic: TopicSpec) -> ObservedTopic:
        check_queue_name(topic.name)
        check_topic_fields(topic, self.kind, MQTT_TOPIC_FIELDS)  # MQTT clients publish to it
        amqp.declare_topic(spec.host, spec.port, topic.name)
        # the agent keeps the record (implicit_topics): the MQTT settings are the bridges' and
        # clients', not the queue's, so they are recorded as given
        return ObservedTopic(name=topic.name, qos=topic.qos, retain=topic.retain)

    def delete_topic(self, spec: BrokerSpec, name: str) -> None:
        check_queue_name(name)
        amqp.delete_topic(spec.host, spec.port, name)

    def observe_topics(self, spec: BrokerSpec) -> list[ObservedTopic]:
        return []

    def essence(self, spec: BrokerSpec) -> dict[str, Any]:
        return {**spec_essence(spec), "mqtt_port": spec.mqtt_port}

    @staticmethod
    def _mqtt_port(spec: BrokerSpec) -> int:
        if spec.mqtt_port is None:
            raise ConfigValueError("mqtt_port", None, "a rabbitmq broker needs pk:mqttPort, the port "
                                   "of its MQTT listener (pk:port is AMQP's)")
        return spec.mqtt_port


def check_queue_name(name: object) -> str:
    """A queue that is also an MQTT topic: no wildcard, not ``amq.``-reserved, ≤ 255 bytes."""
    text = check_text("name", name)
    if "+" in text or "#" in text:
        raise ConfigValueError("name", name, "a topic is a name, not an MQTT filter (+ or #)")
    if text.startswith("amq."):
        raise ConfigValueError("name", name, "RabbitMQ reserves queue names starting with 'amq.'")
    if len(text.encode("utf-8")) > MAX_QUEUE_NAME_BYTES:
        raise ConfigValueError("name", name, f"a queue name is at most {MAX_QUEUE_NAME_BYTES} bytes")
    return text
