"""A Kafka broker of its own is closed by default (issue 13): without ``pk:allowAnonymous true`` it
refuses anonymous clients even when none of its clients has a ``pk:secretRef``, while everything
plantkg runs against it still works; with ``pk:allowAnonymous true`` it is open and ``plan`` warns.

The plant: an open cell Mosquitto on 127.0.0.2 (its camera publishes anonymously) and a Kafka on
127.0.0.3 that says nothing about anonymous clients; the historian reads ``cell.cam`` on Kafka
(rule R1: a bridge worker carries it, logging in as plantkg's own principal) and has no secret.
Checked with confluent-kafka and with Debian's kcat as an independent client:

- an anonymous client gets no metadata and cannot produce; kcat without credentials neither;
- ``plan`` has no changes and no warning for the Kafka, ``status`` says ``users (0)``;
- the bridge worker carries 500 messages, none missing (read back as plantkg's principal);
- ``plantkg check --probe`` passes: its Kafka tap and probe log in;
- the same plant with ``pk:allowAnonymous true`` on the Kafka: ``plan`` warns, ``apply`` opens it,
  the anonymous client and kcat get in, and the bridge still carries.
"""

from __future__ import annotations

import subprocess
from collections.abc import Iterator

import pytest
from confluent_kafka import KafkaException
from confluent_kafka.admin import AdminClient

from engine.security import kafka_client
from tests.integration.agents import Deployment, deployment
from tests.integration.kafka_clients import publish_numbered, read_topic
from tests.integration.test_kafka_auth import _produce

pytestmark = pytest.mark.integration

MQ, KF = "127.0.0.2", "127.0.0.3"
BRIDGED = 500


def _plant(ports: dict[str, int], kafka_extra: str = "") -> str:
    mq_port, kf_port = ports["mq"], ports["kf"]
    return f"""@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix ex: <http://example.org/kafka-closed#> .
ex:mq a pk:Broker ; pk:id "mq" ; pk:name "cell-mqtt" ; pk:brokerType "mosquitto" ; pk:ip "{MQ}" ;
    pk:port {mq_port} ; pk:allowAnonymous true ; pk:hasTopic ex:cam .
ex:kf a pk:Broker ; pk:id "kf" ; pk:name "plant-kafka" ; pk:brokerType "kafka" ; pk:ip "{KF}" ;
    pk:port {kf_port} ; {kafka_extra} pk:hasTopic ex:cam .
ex:cam a pk:Topic ; pk:id "cam" ; pk:name "cell.cam" ; pk:qos 1 ; pk:partitions 1 .
ex:camera a pk:Resource ; pk:id "camera" ; pk:name "Camera" ; pk:sendsTo ex:mq ; pk:publishes ex:cam .
ex:hist a pk:Resource ; pk:id "hist" ; pk:name "Historian" ; pk:sendsTo ex:kf ; pk:subscribes ex:cam .
"""


@pytest.fixture(scope="module")
def plant(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployment]:
    with deployment(tmp_path_factory.mktemp("kafka-closed"), {"mq": MQ, "kf": KF}, _plant) as made:
        yield made


def _anonymous_metadata(bootstrap: str) -> bool:
    """True when a client without credentials reads the broker's metadata."""
    try:
        return bool(AdminClient({"bootstrap.servers": bootstrap, "log_level": 0}).list_topics(timeout=8).brokers)
    except KafkaException:
        return False


def _kcat_metadata(bootstrap: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["kcat", "-b", bootstrap, "-m", "10", "-L"], capture_output=True, text=True, timeout=60)


def _bridged(plant: Deployment, auth: dict[str, str], total: int) -> tuple[int, set[str]]:
    publish_numbered(MQ, plant.ports["mq"], "cell.cam", BRIDGED)
    return read_topic(plant.address("kf"), "cell.cam", auth, total, deadline=90)


def test_an_anonymous_client_and_kcat_are_refused(plant: Deployment) -> None:
    assert not _anonymous_metadata(plant.address("kf"))
    errors = _produce(plant.address("kf"), "cell.cam", {})
    assert errors != [], "an anonymous producer's record was acknowledged"
    done = _kcat_metadata(plant.address("kf"))
    assert done.returncode != 0 and "cell.cam" not in done.stdout, (done.stdout, done.stderr)


def test_the_plan_has_no_warning_and_status_says_users(plant: Deployment, capsys: pytest.CaptureFixture[str]) -> None:
    code = plant.cli("plan", "--detailed-exitcode")
    out = capsys.readouterr().out
    assert code == 0 and "No changes." in out, out
    assert "broker.kf admits anonymous clients" not in out, out
    assert "broker.mq admits anonymous clients" in out, out  # the open Mosquitto still warns
    assert plant.cli("status") == 0
    out = capsys.readouterr().out
    [row] = [line for line in out.splitlines() if line.startswith("kf ")]
    assert "users (0)" in row, out


def test_the_bridge_worker_carries_into_the_closed_kafka(plant: Deployment) -> None:
    got, errors = _bridged(plant, kafka_client.client_settings(True), BRIDGED)
    assert (got, errors) == (BRIDGED, set())


def test_check_taps_and_probes_the_closed_kafka(plant: Deployment, capsys: pytest.CaptureFixture[str]) -> None:
    code = plant.cli("check", "--probe", "--deadline", "30")
    out = capsys.readouterr().out
    assert code == 0, out
    assert "kf" in out, out


def test_allow_anonymous_true_opens_it_and_plan_warns(plant: Deployment, capsys: pytest.CaptureFixture[str]) -> None:
    plant.plant.write_text(_plant(plant.ports, "pk:allowAnonymous true ;"), encoding="utf-8")
    code = plant.cli("plan", "--detailed-exitcode")
    out = capsys.readouterr().out
    assert code == 2, out
    assert ("broker.kf admits anonymous clients (the plant says pk:allowAnonymous true): anyone who reaches "
            f"{KF}:{plant.ports['kf']} may publish and read every topic") in out, out
    assert plant.cli("apply", "--yes") == 0
    capsys.readouterr()
    assert _anonymous_metadata(plant.address("kf"))
    assert _produce(plant.address("kf"), "cell.cam", {}) == []
    done = _kcat_metadata(plant.address("kf"))
    assert done.returncode == 0 and "cell.cam" in done.stdout, (done.stdout, done.stderr)
    assert plant.cli("status") == 0
    out = capsys.readouterr().out
    [row] = [line for line in out.splitlines() if line.startswith("kf ")]
    assert "open" in row, out
    # earlier: BRIDGED bridged + the check's probe (kept: the broker restarted, its data with it)
    # + the anonymous record; now BRIDGED more through the worker, read anonymously
    got, errors = _bridged(plant, {}, 2 * BRIDGED + 2)
    assert (got, errors) == (2 * BRIDGED + 2, set())
