"""The Go load generator (tools/loadgen) against real Mosquittos rendered by the driver: 20k QoS-1
messages from its publisher process to its subscriber process arrive once each, with latencies;
a closed TLS broker refuses it without the plant CA (and admits it with the CA and a login)."""

from __future__ import annotations

import os
import shutil
import struct
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from benchmarks import bench_security as sec
from benchmarks import loadgen
from engine.drivers.mosquitto.driver import MosquittoDriver
from engine.security import ca, principal_key

pytestmark = pytest.mark.integration

GO = shutil.which("go") or ("/usr/local/go/bin/go" if os.access("/usr/local/go/bin/go", os.X_OK) else None)


def test_go_unit_tests_pass() -> None:
    if GO is None:
        pytest.skip("go is not installed")
    done = subprocess.run([GO, "test", "./..."], cwd=loadgen.ROOT / "tools" / "loadgen",
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr


@pytest.fixture(scope="module")
def rig(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[dict[str, sec.Broker], sec.Credentials,
                                                                    sec.Credentials, Path]]:
    loadgen.binary()
    tmp = tmp_path_factory.mktemp("loadgen")
    saved = {k: os.environ.get(k) for k in (principal_key.KEY_ENV, ca.CA_ENV)}
    os.environ[principal_key.KEY_ENV] = str(tmp / "principal-key")
    os.environ[ca.CA_ENV] = str(tmp / "ca")
    found, pub, sub = sec.brokers(tmp)
    started = []
    try:
        for name in ("open", "closed-tls"):
            started.append(found[name].start(MosquittoDriver()))
        yield found, pub, sub, ca.ca_cert_file()
    finally:
        for b in started:
            b.stop()
        for key, value in saved.items():
            if value is None:
                os.environ.pop(key, None)
            else:
                os.environ[key] = value


def test_twenty_thousand_messages_arrive_once_each(rig) -> None:
    found, _pub, _sub, _ca = rig
    target = loadgen.Target(f"{sec.HOST}:{found['open'].spec.port}")
    receiver = loadgen.start("mqtt-sub", target, "lg/t", 20_000, 300.0, ("--idle", "20s"))
    try:
        sent = loadgen.publish(target, "lg/t", 20_000, 100, 300.0)
    except BaseException:
        receiver.stop()
        raise
    got = receiver.result(330.0)
    assert (sent.exit_code, sent.acked, sent.error) == (0, 20_000, None)
    assert (got.exit_code, got.received, got.missing, got.duplicates) == (0, 20_000, 0, 0)
    assert sent.p50_ms > 0 and sent.p99_ms >= sent.p50_ms
    assert got.p50_ms > 0 and got.p99_ms >= got.p50_ms
    assert got.cpu_s > 0 and sent.cpu_s > 0


def test_closed_tls_refuses_it_without_the_ca_or_login_and_admits_it_with_both(rig) -> None:
    found, pub, sub, ca_file = rig
    address = f"{sec.HOST}:{found['closed-tls'].spec.port}"
    for target in (loadgen.Target(address, sub.user, sub.password),  # plain MQTT to a TLS listener
                   loadgen.Target(address, ca_file=ca_file)):  # TLS, anonymous
        with pytest.raises(loadgen.LoadgenError, match="did not get ready: .*connect to"):
            loadgen.start("mqtt-sub", target, sec.TOPIC, 10, 60.0)
    receiver = loadgen.start("mqtt-sub", loadgen.Target(address, sub.user, sub.password, ca_file), sec.TOPIC,
                             500, 120.0, ("--idle", "20s"))
    try:
        sent = loadgen.publish(loadgen.Target(address, pub.user, pub.password, ca_file), sec.TOPIC, 500, 50, 120.0)
    except BaseException:
        receiver.stop()
        raise
    got = receiver.result(150.0)
    assert (sent.acked, got.received, got.missing, got.duplicates) == (500, 500, 0, 0)


def _produce(bootstrap: str, topic: str, count: int) -> None:
    """``count`` records in the load generator's payload format (index, send time in ns)."""
    from confluent_kafka import Producer

    producer = Producer({"bootstrap.servers": bootstrap})
    for i in range(count):
        producer.produce(topic, struct.pack(">Qq", i, time.time_ns()))
    assert producer.flush(60) == 0


def test_kafka_consume_from_the_beginning_and_from_the_end(kafka_broker) -> None:
    from confluent_kafka.admin import AdminClient, NewTopic

    bootstrap, topic = kafka_broker.bootstrap_servers, "lg-kafka"
    admin = AdminClient({"bootstrap.servers": bootstrap})
    admin.create_topics([NewTopic(topic, 2, 1)])[topic].result(60)
    _produce(bootstrap, topic, 2000)
    target = loadgen.Target(bootstrap)
    old = loadgen.start("kafka-consume", target, topic, 2000, 120.0).result(150.0)
    assert (old.exit_code, old.received, old.missing, old.duplicates) == (0, 2000, 0, 0)
    assert old.p99_ms >= old.p50_ms > 0
    # from the end: the 2000 already there are not read; 500 produced after it is ready are
    tail = loadgen.start("kafka-consume", target, topic, 500, 120.0, ("--from", "end"))
    _produce(bootstrap, topic, 500)
    new = tail.result(150.0)
    assert (new.exit_code, new.received, new.missing, new.duplicates) == (0, 500, 0, 0)
