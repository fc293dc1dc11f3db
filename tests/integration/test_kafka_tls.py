"""A Kafka broker of its own with ``pk:tls true`` (issue 13), applied from a plant file on real agents.

The plant: an open cell Mosquitto (pk:allowAnonymous true) on 127.0.0.2 and a Kafka on 127.0.0.3,
open too (pk:allowAnonymous true: clients with the plant CA need no login), whose listeners speak TLS only, with a certificate for 127.0.0.3 issued by its agent from the plant
CA. The camera publishes ``cell.cam`` on Mosquitto, read on Kafka (rule R1: a bridge worker carries
it, speaking TLS to Kafka); ``cell.pos`` is a Kafka topic. Checked with confluent-kafka and with
Debian's kcat as an independent client:

- a plain client gets nothing, a client that trusts another CA fails the handshake;
- kcat with the plant CA writes and reads;
- 1,000 messages published on Mosquitto arrive through the bridge worker, none missing;
- the broker's key file is 0600, ``status`` shows TLS, a second plan has no changes;
- closed (no pk:allowAnonymous, a user with a pk:secretRef), the listener is SASL_SSL: the CA alone gets nothing, the
  user reads what the worker carried.
"""

from __future__ import annotations

import secrets
import stat
import subprocess
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from confluent_kafka import KafkaException
from confluent_kafka.admin import AdminClient

from engine.drivers.kafka import tls
from engine.security import ca
from tests.integration.agents import Deployment, deployment
from tests.integration.kafka_clients import publish_numbered, read_topic

pytestmark = pytest.mark.integration

MQ, KF = "127.0.0.2", "127.0.0.3"
BRIDGED = 1000


def _plant(ports: dict[str, int], kafka_open: str = "pk:allowAnonymous true ;") -> str:
    mq_port, kf_port = ports["mq"], ports["kf"]
    return f"""@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix ex: <http://example.org/kafka-tls#> .
ex:mq a pk:Broker ; pk:id "mq" ; pk:name "cell-mqtt" ; pk:brokerType "mosquitto" ; pk:ip "{MQ}" ;
    pk:port {mq_port} ; pk:allowAnonymous true ; pk:hasTopic ex:cam .
ex:kf a pk:Broker ; pk:id "kf" ; pk:name "plant-kafka" ; pk:brokerType "kafka" ; pk:ip "{KF}" ;
    pk:port {kf_port} ; pk:tls true ; {kafka_open} pk:hasTopic ex:pos , ex:cam .
ex:pos a pk:Topic ; pk:id "pos" ; pk:name "cell.pos" ; pk:partitions 1 .
ex:cam a pk:Topic ; pk:id "cam" ; pk:name "cell.cam" ; pk:qos 1 ; pk:partitions 1 .
ex:camera a pk:Resource ; pk:id "camera" ; pk:name "Camera" ; pk:sendsTo ex:mq ; pk:publishes ex:cam .
ex:hist a pk:Resource ; pk:id "hist" ; pk:name "Historian" ; pk:sendsTo ex:kf ; pk:subscribes ex:pos , ex:cam .
"""


@pytest.fixture(scope="module")
def secure(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployment]:
    with deployment(tmp_path_factory.mktemp("kafka-tls"), {"mq": MQ, "kf": KF}, _plant) as made:
        yield made


def _tls(ca_file: Path | None = None) -> dict[str, str]:
    return {"security.protocol": "ssl", "ssl.ca.location": str(ca_file or ca.ca_cert_file()),
            "ssl.endpoint.identification.algorithm": "https"}


def test_status_shows_tls_and_a_second_plan_changes_nothing(secure: Deployment, capsys: pytest.CaptureFixture[str]) -> None:
    code = secure.cli("plan", "--detailed-exitcode")
    out = capsys.readouterr().out
    assert code == 0 and "No changes." in out, out
    assert secure.cli("status") == 0
    out = capsys.readouterr().out
    [row] = [line for line in out.splitlines() if line.startswith("kf ")]
    assert "TLS" in row, out
    keystore = secure.fleet.agents[KF].state_dir / "brokers" / "kf" / tls.TLS_KEYSTORE_FILE
    assert stat.S_IMODE(keystore.stat().st_mode) == 0o600


def test_a_plain_client_and_one_without_the_plant_ca_get_nothing(secure: Deployment, tmp_path: Path) -> None:
    with pytest.raises(KafkaException):
        AdminClient({"bootstrap.servers": secure.address("kf"), "log_level": 0}).list_topics(timeout=5)
    other = ca.load_or_create_ca(tmp_path / "other-ca")
    with pytest.raises(KafkaException):
        AdminClient({"bootstrap.servers": secure.address("kf"), "log_level": 0,
                     **_tls(other.cert_file)}).list_topics(timeout=5)
    topics = AdminClient({"bootstrap.servers": secure.address("kf"), "log_level": 0, **_tls()}).list_topics(timeout=15)
    assert {"cell.pos", "cell.cam"} <= set(topics.topics)


def test_kcat_writes_and_reads_with_the_plant_ca(secure: Deployment) -> None:
    def kcat(*args: str, stdin: str = "", cafile: Path | None = None) -> subprocess.CompletedProcess[str]:
        return subprocess.run(["kcat", "-X", "security.protocol=ssl", "-X", f"ssl.ca.location={cafile or ca.ca_cert_file()}",
                               "-b", secure.address("kf"), "-m", "10", *args],
                              input=stdin, capture_output=True, text=True, timeout=60)

    marker = uuid.uuid4().hex
    done = kcat("-P", "-t", "cell.pos", stdin=marker + "\n")
    assert done.returncode == 0, done.stderr
    done = kcat("-C", "-t", "cell.pos", "-o", "beginning", "-e")
    assert done.returncode == 0 and marker in done.stdout, done.stderr
    done = subprocess.run(["kcat", "-b", secure.address("kf"), "-m", "5", "-L"], capture_output=True, text=True, timeout=60)
    assert done.returncode != 0, done.stdout


def test_the_bridge_worker_carries_mosquitto_into_the_tls_kafka(secure: Deployment) -> None:
    publish_numbered(MQ, secure.ports["mq"], "cell.cam", BRIDGED)
    got, errors = read_topic(secure.address("kf"), "cell.cam", _tls(), BRIDGED, deadline=90)
    assert (got, errors) == (BRIDGED, set())


def test_a_closed_tls_kafka_takes_its_users_over_sasl_ssl(tmp_path: Path) -> None:
    """The historian with a pk:secretRef closes the Kafka: its listener is SASL_SSL. A client with
    the plant CA but no credentials gets nothing; the historian, over TLS, reads what the bridge
    worker (SASL_SSL as plantkg) carried from Mosquitto."""
    password = secrets.token_urlsafe(18)
    secret = tmp_path / "hist.pw"
    secret.write_text(password + "\n", encoding="utf-8")
    secret.chmod(0o600)

    def plant(ports: dict[str, int]) -> str:
        return _plant(ports, kafka_open="").replace(
            "pk:subscribes ex:pos , ex:cam .", f'pk:subscribes ex:pos , ex:cam ; pk:secretRef "file:{secret}" .')

    with deployment(tmp_path, {"mq": MQ, "kf": KF}, plant) as made:
        kafka = made.address("kf")
        with pytest.raises(KafkaException):
            AdminClient({"bootstrap.servers": kafka, "log_level": 0, **_tls()}).list_topics(timeout=5)
        publish_numbered(MQ, made.ports["mq"], "cell.cam", 200)
        hist = {**_tls(), "security.protocol": "sasl_ssl", "sasl.mechanism": "SCRAM-SHA-512",
                "sasl.username": "hist", "sasl.password": password}
        assert read_topic(kafka, "cell.cam", hist, 200, deadline=90) == (200, set())
