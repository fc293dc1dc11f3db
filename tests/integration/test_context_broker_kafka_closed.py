"""The context broker's ``kafka://`` notifications reach a closed Kafka (issue 13), end to end:
``plantkg apply`` of a plant file with a Kafka that says nothing about anonymous clients (closed
by default) and a context broker, real agents, Kafka and context broker.

- the engine tells the context broker the plant's closed Kafka (``closed_kafkas``, the command
  line's ``--closed-kafka``) and the plan has no change after apply;
- a subscription's notifications arrive in the closed Kafka, every one, in order: the context
  broker logs in as plantkg's own Kafka principal (read back as plantkg);
- the anonymous path stays refused: a context broker not told the Kafka (started by hand, no
  ``--closed-kafka``) sends without credentials, its notifications fail (the subscription says so)
  and none arrives; a client without credentials gets no metadata either.
"""

from __future__ import annotations

import json
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import requests
from confluent_kafka import Consumer, KafkaError, KafkaException
from confluent_kafka.admin import AdminClient

from benchmarks.context_broker_rig import ContextBroker
from engine.security import kafka_client
from tests.integration.agents import Deployment, deployment

pytestmark = pytest.mark.integration

KF, CB, OTHER = "127.0.0.3", "127.0.0.4", "127.0.0.5"
TOPIC = "cb.notify"
UPDATES = 20

PLANT = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix ex: <http://example.org/cb-kafka-closed#> .
ex:kf a pk:Broker ; pk:id "kf" ; pk:name "plant-kafka" ; pk:brokerType "kafka" ; pk:ip "{kf}" ;
    pk:port {kf_port} ; pk:hasTopic ex:notify .
ex:notify a pk:Topic ; pk:id "notify" ; pk:name "{topic}" ; pk:partitions 1 .
ex:hist a pk:Resource ; pk:id "hist" ; pk:name "Historian" ; pk:sendsTo ex:kf ; pk:subscribes ex:notify .
ex:cb a pk:Broker ; pk:id "cb" ; pk:name "context" ; pk:brokerType "ngsi-v2" ; pk:ip "{cb}" ;
    pk:port {cb_port} ; pk:hasTopic ex:state .
ex:state a pk:Topic ; pk:id "state" ; pk:name "agv/1/state" ; pk:entityType "AgvState" .
ex:agv a pk:Resource ; pk:id "agv" ; pk:name "AGV 1" ; pk:sendsTo ex:cb ; pk:publishes ex:state .
"""


def _plant(ports: dict[str, int]) -> str:
    return PLANT.format(kf=KF, kf_port=ports["kf"], cb=CB, cb_port=ports["cb"], topic=TOPIC)


@pytest.fixture(scope="module")
def dep(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployment]:
    with deployment(tmp_path_factory.mktemp("cb-kafka-closed"), {"kf": KF, "cb": CB}, _plant) as made:
        yield made


def subscribe(url: str, token: str, bootstrap: str, entity_id: str) -> str:
    doc = {"subject": {"entities": [{"id": entity_id}]},
           "notification": {"kafka": {"url": f"kafka://{bootstrap}", "topic": TOPIC}, "attrsFormat": "keyValues"}}
    answer = requests.post(f"{url}/v2/subscriptions", json=doc, timeout=10,
                           headers={"Authorization": f"Bearer {token}"})
    assert answer.status_code == 201, answer.text
    return answer.headers["Location"].rsplit("/", 1)[1]


def write_updates(url: str, token: str, entity_id: str, count: int) -> None:
    auth = {"Authorization": f"Bearer {token}"}
    for seq in range(count):
        body = {"id": entity_id, "type": "AgvState", "seq": {"type": "Number", "value": seq}}
        answer = requests.post(f"{url}/v2/entities?options=upsert", json=body, headers=auth, timeout=10)
        assert answer.status_code in (201, 204), answer.text


def notifications(bootstrap: str, entity_id: str, want: int, deadline: float, tls: bool = False) -> list[Any]:
    """The ``seq`` of each notification of ``entity_id`` in the topic (read from its beginning as
    plantkg; ``tls``: over TLS), until ``want`` of them or ``deadline`` seconds."""
    consumer = Consumer({"bootstrap.servers": bootstrap, "group.id": f"t-{uuid.uuid4().hex[:8]}",
                         "auto.offset.reset": "earliest", "log_level": 0,
                         **kafka_client.client_settings(True, tls=tls)})
    seqs: list[Any] = []
    end = time.monotonic() + deadline
    try:
        consumer.subscribe([TOPIC])
        while len(seqs) < want and time.monotonic() < end:
            for msg in consumer.consume(100, 0.5):
                if msg.error():
                    if msg.error().code() != KafkaError._PARTITION_EOF:
                        raise KafkaException(msg.error())
                    continue
                [data] = json.loads(msg.value())["data"]
                if data["id"] == entity_id:
                    seqs.append(data["seq"])
    finally:
        consumer.close()
    return seqs


def shown_when(url: str, token: str, sub_id: str, done: Any, deadline: float = 60.0) -> dict[str, Any]:
    """The subscription as shown once ``done(it)`` holds (polled until ``deadline``)."""
    end = time.monotonic() + deadline
    while True:
        shown = requests.get(f"{url}/v2/subscriptions/{sub_id}", timeout=10,
                             headers={"Authorization": f"Bearer {token}"}).json()
        if done(shown) or time.monotonic() > end:
            return shown
        time.sleep(0.5)  # polling the subscription's status, bounded by the deadline above


def test_the_context_broker_is_told_the_closed_kafka_and_the_plan_is_settled(
        dep: Deployment, capsys: pytest.CaptureFixture[str]) -> None:
    assert dep.fleet.brokers()["cb"].spec.closed_kafkas == (dep.address("kf"),)
    code = dep.cli("plan", "--detailed-exitcode")
    out = capsys.readouterr().out
    assert code == 0 and "No changes." in out, out


def notifications_arrive(dep: Deployment, tls: bool = False) -> None:
    """A subscription of the context broker ``cb`` to a new entity, ``UPDATES`` writes of it: each
    notification arrives in Kafka ``kf`` in order (read as plantkg, over TLS with ``tls``), and
    the subscription shows them all sent, no failure."""
    url, token = f"http://{CB}:{dep.ports['cb']}", dep.fleet.agents[CB].token
    entity_id = f"urn:ngsi-ld:AgvState:{uuid.uuid4().hex[:8]}"
    sub_id = subscribe(url, token, dep.address("kf"), entity_id)
    write_updates(url, token, entity_id, UPDATES)
    assert notifications(dep.address("kf"), entity_id, UPDATES, deadline=90, tls=tls) == list(range(UPDATES))
    shown = shown_when(url, token, sub_id, lambda s: s["notification"].get("timesSent") == UPDATES)
    assert shown["notification"].get("timesSent") == UPDATES and "lastFailure" not in shown["notification"], shown


def test_notifications_arrive_in_the_closed_kafka(dep: Deployment) -> None:
    notifications_arrive(dep)


def test_the_anonymous_path_stays_refused(dep: Deployment, tmp_path: Path) -> None:
    assert _metadata_or_none(dep.address("kf")) is None  # a client without credentials gets nothing
    other = ContextBroker(tmp_path / "cb-not-told", host=OTHER).start()  # no --closed-kafka
    try:
        entity_id = f"urn:ngsi-ld:AgvState:{uuid.uuid4().hex[:8]}"
        sub_id = subscribe(other.url, other.token, dep.address("kf"), entity_id)
        write_updates(other.url, other.token, entity_id, 1)
        shown = shown_when(other.url, other.token, sub_id, lambda s: "lastFailure" in s["notification"])
        assert shown["status"] == "failed" and "lastSuccess" not in shown["notification"], shown
        assert "Kafka" in shown["notification"].get("lastFailureReason", ""), shown
    finally:
        other.stop()
    assert notifications(dep.address("kf"), entity_id, 1, deadline=10) == []


def _metadata_or_none(bootstrap: str) -> object:
    """The metadata an anonymous client reads, or None when it is refused."""
    try:
        metadata = AdminClient({"bootstrap.servers": bootstrap, "log_level": 0}).list_topics(timeout=8)
    except KafkaException:
        return None
    return metadata if metadata.brokers else None
