"""A three-node KRaft cluster and a MirrorMaker 2 from a plant file, on real agents and real JVMs.

ontology/examples/kafka-cluster.ttl (ports made free): the plant cluster's nodes on 127.0.0.2-4,
each on its own agent, the site cluster's node on 127.0.0.5, a Mosquitto on 127.0.0.2. One
deployment is shared by the module (four JVMs and a MirrorMaker take a minute or two to come up on
two cores); the tests run in file order and each leaves the cluster serving:

1. the cluster formed: three nodes of one KRaft cluster id, topics with replication factor 3 and
   min.insync.replicas 2, created once;
2. 20,000 numbered records produced with acks=all while one node is killed with SIGKILL: none is
   missing, and the node rejoins (in sync again) once its agent restarted it;
3. ``apply`` raises partitions and changes topic configs, and rolls a cluster-wide config change one
   node at a time, while a producer with acks=all keeps writing: no write fails; lowering
   partitions is refused (exit 2, naming the topic and the field);
4. MirrorMaker 2 copies 10,000 records from the plant cluster to the site cluster with none
   missing, and ``status`` shows the mirror with its lag.
"""

from __future__ import annotations

import json
import os
import re
import signal
import threading
import time
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from confluent_kafka import Consumer, KafkaError, Producer, TopicPartition
from confluent_kafka.admin import AdminClient, ConfigResource, ResourceType

from engine import process
from engine.cli import main
from engine.model import BridgeStatus, BrokerStatus
from tests.integration.agents import AgentFleet, plant_copy, start_agents

pytestmark = pytest.mark.integration

NODES = {"plant-kafka-1": "127.0.0.2", "plant-kafka-2": "127.0.0.3", "plant-kafka-3": "127.0.0.4"}
SITE = "site-kafka-1"
HOSTS = ["127.0.0.2", "127.0.0.3", "127.0.0.4", "127.0.0.5"]
RECORDS = 20_000
MIRRORED = 10_000


@dataclass
class Deployed:
    fleet: AgentFleet
    plant: Path
    ports: dict[str, int]
    capsys: object = None
    outputs: list[str] = field(default_factory=list)

    @property
    def bootstrap(self) -> str:
        return ",".join(f"{host}:{self.ports[node]}" for node, host in NODES.items())

    @property
    def site(self) -> str:
        return f"127.0.0.5:{self.ports[SITE]}"

    def run(self, *args: object) -> tuple[int, str]:
        code = main([str(a) for a in args])
        out = self.capsys.readouterr()  # type: ignore[attr-defined]
        return code, out.out + out.err


@pytest.fixture(scope="module")
def deployed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployed]:
    tmp = tmp_path_factory.mktemp("kafka-cluster")
    fleet = start_agents(HOSTS, tmp)
    try:
        plant, ports = plant_copy("kafka-cluster.ttl", tmp)
        yield Deployed(fleet, plant, ports)
        code = main(["destroy", str(plant), "--agents", str(fleet.agents_file), "--yes"])
        assert code == 0
        assert fleet.brokers() == {}
    finally:
        fleet.stop()


@pytest.fixture()
def cluster(deployed: Deployed, capsys: pytest.CaptureFixture[str]) -> Deployed:
    deployed.capsys = capsys
    return deployed


def test_apply_forms_one_cluster_with_replicated_topics(cluster: Deployed) -> None:
    code, out = cluster.run("apply", cluster.plant, "--agents", cluster.fleet.agents_file, "--yes")
    assert code == 0, out
    # 5 brokers (3 + 1 Kafka nodes, 1 Mosquitto), 6 topics (3 on the plant cluster, planned once,
    # on its lead node; 1 on the site's; 2 on Mosquitto), 2 bridges (a worker, a mirror)
    assert "Plan: 13 to create, 0 to update, 0 to replace, 0 to destroy." in out, out
    brokers = cluster.fleet.brokers()
    ids = set()
    for node, host in NODES.items():
        have = brokers[node]
        assert have.spec.host == host and have.status is BrokerStatus.RUNNING  # type: ignore[attr-defined]
        meta = (cluster.fleet.agents[host].state_dir / "brokers" / node / "data" / "meta.properties").read_text()
        ids.add(re.search(r"cluster\.id=(\S+)", meta).group(1))  # type: ignore[union-attr]
        assert re.search(rf"node\.id={node[-1]}\b", meta), meta
    assert len(ids) == 1, ids
    admin = AdminClient({"bootstrap.servers": cluster.bootstrap})
    meta = admin.list_topics(timeout=10)
    assert sorted(meta.brokers) == [1, 2, 3]
    for name in ("line.energy", "line.status", "plant.kpi"):
        topic = meta.topics[name]
        assert len(topic.partitions) == 3
        assert all(sorted(p.replicas) == [1, 2, 3] for p in topic.partitions.values()), name
    assert _topic_config(admin, "line.energy", "min.insync.replicas") == "2"
    assert _topic_config(admin, "plant.kpi", "min.insync.replicas") == "2"  # the cluster's default
    code, out = cluster.run("plan", cluster.plant, "--agents", cluster.fleet.agents_file, "--detailed-exitcode")
    assert code == 0 and "No changes." in out, out


def test_no_acknowledged_record_is_lost_when_a_node_is_killed(cluster: Deployed) -> None:
    victim, host = "plant-kafka-3", NODES["plant-kafka-3"]
    before = cluster.fleet.brokers()[victim]
    killed = threading.Event()

    def kill_at(sent: int) -> None:
        if sent == RECORDS // 4 and not killed.is_set():
            os.kill(before.pid, signal.SIGKILL)  # type: ignore[attr-defined]
            killed.set()

    errors = _produce(cluster.bootstrap, "line.energy", RECORDS, tag="kill", on_sent=kill_at)
    assert killed.is_set()
    assert errors == [], errors[:5]
    got = _consume_numbers(cluster.bootstrap, "line.energy", "kill", RECORDS)
    assert got == set(range(RECORDS)), f"{RECORDS - len(got)} missing"

    def rejoined() -> bool:
        have = cluster.fleet.client(host).get_broker(victim)
        return (have is not None and have.status is BrokerStatus.RUNNING and have.restarts >= 1
                and have.pid != before.pid)  # type: ignore[attr-defined]

    process.wait_until(rejoined, 180, 0.5, what=f"{victim} to be restarted by its agent")
    # back in every partition's ISR once it has fetched what it missed (Kafka's follower catch-up,
    # seconds on a loaded machine); the wait raises, naming it, if that never happens
    process.wait_until(lambda: _in_sync(cluster.bootstrap, 3), 120, 0.5,
                       what=f"{victim} back in the in-sync replicas of every partition", ignore=(KeyError,))


def test_apply_changes_the_cluster_while_it_serves(cluster: Deployed) -> None:
    text = cluster.plant.read_text(encoding="utf-8")
    changed = text.replace("pk:partitions 3 ;\n    pk:replicationFactor 3 ;\n    pk:minInsyncReplicas 2 ;\n"
                           "    pk:retentionMs 604800000 .",
                           "pk:partitions 6 ;\n    pk:replicationFactor 3 ;\n    pk:minInsyncReplicas 2 ;\n"
                           "    pk:retentionMs 86400000 .")
    changed = changed.replace('pk:brokerType "kafka" ;\n    pk:minInsyncReplicas 2 ;',
                              'pk:brokerType "kafka" ;\n    pk:minInsyncReplicas 1 ;')
    assert changed.count("pk:partitions 6") == 1 and "pk:minInsyncReplicas 1 ;" in changed
    cluster.plant.write_text(changed, encoding="utf-8")
    code, out = cluster.run("plan", cluster.plant, "--agents", cluster.fleet.agents_file)
    assert code == 0, out
    assert "Plan: 0 to create, 1 to update, 3 to replace, 0 to destroy." in out, out

    stop = threading.Event()
    results: dict[str, object] = {}
    writer = threading.Thread(target=lambda: results.update(
        errors=_produce(cluster.bootstrap, "line.energy", None, tag="roll", stop=stop, results=results)))
    writer.start()
    try:
        code, out = cluster.run("apply", cluster.plant, "--agents", cluster.fleet.agents_file, "--yes")
    finally:
        stop.set()
        writer.join(120)
    assert code == 0, out
    assert results["errors"] == [], results["errors"][:5]  # type: ignore[index]
    sent = int(results["sent"])  # type: ignore[arg-type]
    assert sent > 100, sent
    got = _consume_numbers(cluster.bootstrap, "line.energy", "roll", sent)
    assert got == set(range(sent)), f"{sent - len(got)} of {sent} missing"
    # the nodes restarted one after another: their start times are in node order, apart
    starts = [cluster.fleet.brokers()[n].started_at for n in NODES]  # type: ignore[attr-defined]
    assert starts == sorted(starts), starts
    admin = AdminClient({"bootstrap.servers": cluster.bootstrap})
    assert len(admin.list_topics(timeout=10).topics["line.energy"].partitions) == 6
    assert _topic_config(admin, "line.energy", "retention.ms") == "86400000"
    # a change Kafka cannot make is refused before anything is touched, naming topic and field
    cluster.plant.write_text(changed.replace("pk:partitions 6", "pk:partitions 2"), encoding="utf-8")
    code, out = cluster.run("plan", cluster.plant, "--agents", cluster.fleet.agents_file)
    assert code == 2, out
    assert "topic.plant-kafka-1.line.energy" in out and "partitions 6 → 2" in out, out
    cluster.plant.write_text(changed, encoding="utf-8")


def test_mirrormaker_copies_every_record_to_the_site(cluster: Deployed) -> None:
    errors = _produce(cluster.bootstrap, "plant.kpi", MIRRORED, tag="mirror")
    assert errors == [], errors[:5]
    got = _consume_numbers(cluster.site, "plant.kpi", "mirror", MIRRORED, deadline=240)
    assert got == set(range(MIRRORED)), f"{MIRRORED - len(got)} missing on the site"
    host = "127.0.0.5"

    def caught_up():  # type: ignore[no-untyped-def]
        [mirror] = [b for b in cluster.fleet.client(host).list_bridges()]
        # a snapshot taken before the records came also says lag 0: wait for one counting them
        done = mirror.status is BridgeStatus.RUNNING and mirror.lag == 0 and (mirror.forwarded or 0) >= MIRRORED
        return mirror if done else None

    mirror = process.wait_until(caught_up, 60, 0.5, what="the mirror to report every record copied, lag 0")
    assert mirror.spec.mechanism.value == "kafka-mirror" and mirror.forwarded >= MIRRORED
    code, out = cluster.run("status", cluster.plant, "--agents", cluster.fleet.agents_file, "--format", "json")
    assert code == 0, out
    [row] = [b for b in json.loads(out)["bridges"] if b["mechanism"] == "kafka-mirror"]
    assert row["status"] == "running" and row["lag"] == 0, row


# --- helpers ---------------------------------------------------------------------------------


def _produce(bootstrap: str, topic: str, count: int | None, *, tag: str, on_sent=None,  # type: ignore[no-untyped-def]
             stop: threading.Event | None = None, results: dict[str, object] | None = None) -> list[str]:
    """Produce records ``"<tag>:<n>"`` with acks=all (idempotent), ``count`` of them or until
    ``stop``; return the delivery errors."""
    errors: list[str] = []
    producer = Producer({"bootstrap.servers": bootstrap, "acks": "all", "enable.idempotence": True,
                         "linger.ms": 5, "delivery.timeout.ms": 180_000})

    def delivered(err, _msg) -> None:  # type: ignore[no-untyped-def]
        if err is not None:
            errors.append(str(err))

    n = 0
    while (count is None or n < count) and not (stop is not None and stop.is_set()):
        try:
            producer.produce(topic, value=f"{tag}:{n}".encode(), on_delivery=delivered)
        except BufferError:
            producer.poll(0.1)
            continue
        n += 1
        if on_sent is not None:
            on_sent(n)
        if count is None:
            time.sleep(0.005)  # a steady stream while apply runs
        producer.poll(0)
    assert producer.flush(240) == 0, "records left unsent"
    if results is not None:
        results["sent"] = n
    return errors


def _consume_numbers(bootstrap: str, topic: str, tag: str, expect: int, deadline: float = 120) -> set[int]:
    """The numbers of the ``tag`` records of ``topic``, read from the beginning."""
    consumer = Consumer({"bootstrap.servers": bootstrap, "group.id": f"it-{uuid.uuid4().hex[:8]}",
                         "auto.offset.reset": "earliest", "enable.auto.commit": False})
    seen: set[int] = set()
    prefix = f"{tag}:".encode()
    try:
        consumer.subscribe([topic])
        end = time.monotonic() + deadline
        while len(seen) < expect and time.monotonic() < end:
            for msg in consumer.consume(1000, 1.0):
                if msg.error():
                    if msg.error().code() != KafkaError._PARTITION_EOF:
                        raise AssertionError(msg.error())
                    continue
                if msg.value().startswith(prefix):
                    seen.add(int(msg.value()[len(prefix):]))
    finally:
        consumer.close()
    return seen


def _topic_config(admin: AdminClient, topic: str, key: str) -> str:
    resource = ConfigResource(ResourceType.TOPIC, topic)
    return admin.describe_configs([resource])[resource].result(30)[key].value


def _in_sync(bootstrap: str, replicas: int) -> bool:
    meta = AdminClient({"bootstrap.servers": bootstrap}).list_topics(timeout=10)
    return all(len(p.isrs) == replicas for t in ("line.energy", "line.status", "plant.kpi")
               for p in meta.topics[t].partitions.values())
