"""Smoke test: the parts `make setup` installs are real and work together with our runtime code.

A real Mosquitto (Debian package) and a real Kafka broker (KRaft, jars from Maven Central) are
started on free loopback ports with configs rendered by engine.*_runtime; one message goes through
each with the Python clients the drivers will use; both are stopped and must be gone.
"""

from __future__ import annotations

import queue
import uuid
from pathlib import Path

import pytest
from confluent_kafka import Consumer, KafkaException, Producer, TopicPartition
from confluent_kafka.admin import AdminClient, NewTopic
from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import netutil, parts, process
from engine.drivers.mosquitto import runtime as mosquitto_runtime

pytestmark = pytest.mark.integration

HOST = "127.0.0.1"


def test_mosquitto_qos1_roundtrip(tmp_path: Path) -> None:
    port = netutil.free_port(HOST)
    cfg = mosquitto_runtime.MosquittoConfig(
        host=HOST,
        port=port,
        log_file=tmp_path / "mosquitto.log",
        run_as=mosquitto_runtime.default_run_as(),
    )
    conf = tmp_path / "mosquitto.conf"
    conf.write_text(mosquitto_runtime.render_mosquitto_conf(cfg), encoding="utf-8")
    argv = mosquitto_runtime.mosquitto_command(parts.mosquitto_binary(), conf)
    broker = process.spawn(argv, log_dir=tmp_path, name="mosquitto-stdout")
    clients: list[mqtt.Client] = []
    try:
        process.wait_until(
            lambda: netutil.port_open(HOST, port), 10.0, 0.005,
            what=f"Mosquitto to listen on {HOST}:{port}", child=broker,
        )
        received: queue.Queue[mqtt.MQTTMessage] = queue.Queue()
        subscribed: queue.Queue[list] = queue.Queue()
        topic = f"plantkg/smoke/{uuid.uuid4().hex}"

        sub = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="plantkg-smoke-sub")
        sub.on_message = lambda _c, _u, msg: received.put(msg)
        sub.on_subscribe = lambda _c, _u, _mid, codes, _p: subscribed.put(codes)
        pub = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="plantkg-smoke-pub")
        for client in (sub, pub):
            clients.append(client)
            client.connect(HOST, port, keepalive=10)
            client.loop_start()
            process.wait_until(client.is_connected, 10.0, 0.005, what="MQTT CONNACK")

        sub.subscribe(topic, qos=1)
        codes = subscribed.get(timeout=10)
        assert [c.value for c in codes] == [1], f"SUBACK granted {codes}"

        info = pub.publish(topic, b"hello from plantkg", qos=1)
        info.wait_for_publish(timeout=10)
        assert info.is_published(), "no PUBACK for the QoS-1 message"
        msg = received.get(timeout=10)
        assert (msg.topic, msg.payload, msg.qos) == (topic, b"hello from plantkg", 1)
    finally:
        for client in clients:
            client.disconnect()
            client.loop_stop()
        process.stop(broker, grace=5.0)

    assert not broker.group_alive()
    assert not netutil.port_open(HOST, port)
    log = cfg.log_file.read_text(encoding="utf-8")
    assert "running" in log and "plantkg-smoke-pub" in log, log


def test_kafka_topic_produce_consume(kafka_broker) -> None:
    bootstrap = kafka_broker.bootstrap_servers
    admin = AdminClient({"bootstrap.servers": bootstrap})

    # Readiness from a client's view: metadata lists a broker (raises KafkaException until then).
    metadata = process.wait_until(
        lambda: admin.list_topics(timeout=2).brokers,
        90.0, 0.2, what=f"Kafka metadata from {bootstrap}",
        child=kafka_broker.child, ignore=(KafkaException,),
    )
    assert len(metadata) == 1

    topic = f"plantkg-smoke-{uuid.uuid4().hex[:8]}"
    futures = admin.create_topics([NewTopic(topic, num_partitions=1, replication_factor=1)])
    futures[topic].result(timeout=30)

    delivered: list = []
    producer = Producer({"bootstrap.servers": bootstrap, "acks": "all"})
    producer.produce(topic, key=b"k", value=b"hello from plantkg",
                     on_delivery=lambda err, msg: delivered.append((err, msg)))
    assert producer.flush(30) == 0, "message still queued after 30 s"
    assert len(delivered) == 1 and delivered[0][0] is None, f"delivery failed: {delivered}"

    consumer = Consumer({
        "bootstrap.servers": bootstrap,
        "group.id": f"plantkg-smoke-{uuid.uuid4().hex[:8]}",
        "enable.auto.commit": False,
    })
    try:
        consumer.assign([TopicPartition(topic, 0, 0)])

        def poll_one():
            msg = consumer.poll(0.5)
            if msg is not None and msg.error():
                raise KafkaException(msg.error())
            return msg

        msg = process.wait_until(poll_one, 30.0, 0.0, what=f"a message on {topic}")
        assert (msg.key(), msg.value()) == (b"k", b"hello from plantkg")
    finally:
        consumer.close()
