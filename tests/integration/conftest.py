"""Real brokers for integration tests.

Kafka's JVM start dominates the suite, so one Kafka broker serves the whole session
(:func:`kafka_broker`, started on first use); its teardown stops it and fails if any process of
its group survives. Mosquitto starts in milliseconds, so tests start their own.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from engine import netutil, parts, process
from engine.drivers.kafka import runtime as kafka_runtime

KAFKA_READY_DEADLINE = 90.0


@dataclass(frozen=True)
class KafkaBroker:
    config: kafka_runtime.KafkaNodeConfig
    child: process.Child
    broker_dir: Path

    @property
    def bootstrap_servers(self) -> str:
        return self.config.bootstrap_servers


def start_kafka(broker_dir: Path, host: str = "127.0.0.1") -> KafkaBroker:
    """Render config, format storage, spawn the broker and wait until its port accepts."""
    kafka, java = parts.kafka_parts(), parts.java_binary()
    port, controller_port = netutil.free_ports(2, host)
    cfg = kafka_runtime.KafkaNodeConfig(
        host=host, port=port, controller_port=controller_port, data_dir=broker_dir / "data"
    )
    properties = broker_dir / "server.properties"
    broker_dir.mkdir(parents=True, exist_ok=True)
    properties.write_text(kafka_runtime.render_server_properties(cfg), encoding="utf-8")
    kafka_runtime.format_storage(cfg, properties, broker_dir, kafka=kafka, java=java)
    argv = kafka_runtime.broker_command(kafka, java, properties, logs_dir=broker_dir / "logs")
    child = process.spawn(argv, log_dir=broker_dir / "logs", name="kafka")
    try:
        process.wait_until(
            lambda: netutil.port_open(host, port),
            KAFKA_READY_DEADLINE,
            0.1,
            what=f"Kafka to listen on {host}:{port}",
            child=child,
        )
    except BaseException:
        process.stop(child)
        raise
    return KafkaBroker(cfg, child, broker_dir)


@pytest.fixture(scope="session")
def kafka_broker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[KafkaBroker]:
    broker = start_kafka(tmp_path_factory.mktemp("kafka"))
    yield broker
    process.stop(broker.child, grace=30.0)
    assert not broker.child.group_alive(), f"Kafka (pid {broker.child.pid}) survived stop()"
    assert not netutil.port_open(broker.config.host, broker.config.port)
