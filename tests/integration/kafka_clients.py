"""Clients the Kafka security tests share: read a topic from its beginning with confluent-kafka,
and publish a run of numbered MQTT messages (QoS 1, each acknowledged) with paho."""

from __future__ import annotations

import secrets
import time
import uuid
from collections.abc import Iterable
from pathlib import Path

from confluent_kafka import Consumer, KafkaError
from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion


def read_topic(bootstrap: str, topic: str, auth: dict[str, str], want: int,
               deadline: float = 30) -> tuple[int, set[str]]:
    """(records read, error names) from the beginning of ``topic``, in a fresh consumer group,
    until ``want`` records, an error, or ``deadline`` seconds."""
    consumer = Consumer({"bootstrap.servers": bootstrap, "group.id": f"t-{uuid.uuid4().hex[:8]}",
                         "auto.offset.reset": "earliest", "log_level": 0, **auth})
    got, errors = 0, set()
    end = time.monotonic() + deadline
    try:
        consumer.subscribe([topic])
        while got < want and time.monotonic() < end and not errors:
            for msg in consumer.consume(500, 0.5):
                if msg.error():
                    if msg.error().code() != KafkaError._PARTITION_EOF:
                        errors.add(msg.error().name())
                else:
                    got += 1
    finally:
        consumer.close()
    return got, errors


def password_files(folder: Path, names: Iterable[str]) -> tuple[dict[str, str], dict[str, Path]]:
    """A throwaway password per name and the 0600 file holding it (``folder/<name>.pw``), for
    ``pk:secretRef "file:..."``: (passwords, files)."""
    passwords = {name: secrets.token_urlsafe(18) for name in names}
    files = {}
    for name, password in passwords.items():
        files[name] = folder / f"{name}.pw"
        files[name].write_text(password + "\n", encoding="utf-8")
        files[name].chmod(0o600)
    return passwords, files


def publish_numbered(host: str, port: int, topic: str, count: int) -> None:
    """Publish ``0`` .. ``count - 1`` to ``topic`` at QoS 1, anonymously; return once each is
    acknowledged (30 s each at most)."""
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"pub-{uuid.uuid4().hex[:6]}")
    client.connect(host, port)
    client.loop_start()
    try:
        infos = [client.publish(topic, f"{n}".encode(), qos=1) for n in range(count)]
        for info in infos:
            info.wait_for_publish(30)
    finally:
        client.loop_stop()
        client.disconnect()
