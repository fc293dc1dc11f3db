"""Turning ``pk:tls`` on for a *running* Kafka cluster, or closing it (issue 13): a whole-cluster
restart.

A rolling restart cannot change a cluster's listener security (a node on the new listeners cannot
reach the nodes still on the old ones), so the plan marks such a replacement "whole cluster" and
apply restarts every node at once (engine.plan.restarts_whole_cluster, engine.apply_calls).

The plant: an open cluster ``plant-kafka`` (``pk:allowAnonymous true``, no ``pk:tls``), its three
combined nodes on 127.0.0.2-4, each on its own agent; ``line.energy`` has 3 replicas and
min.insync.replicas 2. Each test deploys its own (three JVMs take a minute to come up on two
cores; run this file alone with ``-n 1``). Turning TLS on:

1. a plain client writes numbered records with acks=all;
2. the plant file gains ``pk:tls true`` on the cluster: ``plan`` shows each node replaced as a
   whole-cluster restart, ``apply`` exits 0;
3. every node's listeners (client, inter-broker, controller) are SSL, nothing plain; a plain client
   gets nothing; a client trusting the plant CA reads every record written before the change, and
   writes through each node with acks=all, every partition keeping its 3 replicas in sync;
4. a second ``plan`` is empty.

Closing it (``pk:allowAnonymous`` removed, the PLC and the MES given a ``pk:secretRef``): every
listener is SASL_PLAINTEXT, an anonymous client gets nothing, the MES reads every record written
before the change, a second ``plan`` is empty. With the nodes rolled one at a time instead, either
apply fails (exit 3).
"""

from __future__ import annotations

from pathlib import Path

import pytest
from confluent_kafka import KafkaException
from confluent_kafka.admin import AdminClient

from engine import process
from engine.security import ca
from tests.integration.agents import Deployment, deployment
from tests.integration.kafka_clients import password_files, read_topic
from tests.integration.test_kafka_auth import _as, _produce
from tests.integration.test_kafka_cluster_closed import cluster_nodes
from tests.integration.test_kafka_cluster_tls_open import trusting

pytestmark = pytest.mark.integration

NODES = {"n1": "127.0.0.2", "n2": "127.0.0.3", "n3": "127.0.0.4"}
BEFORE = 50


def _plant(ports: dict[str, int], tls: bool = False, logins: dict[str, Path] | None = None) -> str:
    """The open, plain cluster; ``tls``: it says ``pk:tls true``; ``logins``: it is closed (no
    ``pk:allowAnonymous``) and the PLC and the MES log in with those password files."""
    nodes = cluster_nodes(ports, NODES)
    says = (" pk:tls true ;" if tls else "") + ("" if logins else " pk:allowAnonymous true ;")
    login = {name: f' ;\n    pk:secretRef "file:{logins[name]}"' if logins else "" for name in ("plc", "mes")}
    return f"""@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix ex: <http://example.org/kafka-cluster-tls-toggle#> .
ex:c a pk:Broker ; pk:id "plant-kafka" ; pk:name "plant-kafka" ; pk:brokerType "kafka" ;{says}
    pk:minInsyncReplicas 2 ; pk:hasTopic ex:energy .
{nodes}ex:energy a pk:Topic ; pk:id "energy" ; pk:name "line.energy" ; pk:partitions 3 ;
    pk:replicationFactor 3 ; pk:minInsyncReplicas 2 .
ex:plc a pk:Resource ; pk:id "plc" ; pk:name "PLC" ; pk:sendsTo ex:c ; pk:publishes ex:energy{login['plc']} .
ex:mes a pk:Resource ; pk:id "mes" ; pk:name "MES" ; pk:sendsTo ex:c ; pk:subscribes ex:energy{login['mes']} .
"""


def _change(cluster: Deployment, plant: str, capsys: pytest.CaptureFixture[str]) -> None:
    """Write ``plant``; ``plan`` shows every node replaced as a whole-cluster restart; ``apply``."""
    cluster.plant.write_text(plant, encoding="utf-8")
    capsys.readouterr()
    assert cluster.cli("plan") == 0
    out = capsys.readouterr().out
    for node in NODES:
        assert f"broker.{node}" in out, out
    assert out.count("whole cluster: listener security changes") == len(NODES), out
    assert cluster.cli("apply", "--yes") == 0, capsys.readouterr()
    capsys.readouterr()


def _speaks(cluster: Deployment, protocol: str) -> None:
    """Every node's client, inter-broker and controller listeners speak ``protocol``, and a plain
    anonymous client gets nothing from the cluster."""
    for node, host in NODES.items():
        props = (cluster.fleet.agents[host].state_dir / "brokers" / node / "server.properties").read_text()
        assert f"\nlisteners={protocol}://{host}:{cluster.ports[node]},CONTROLLER://" in props, props
        assert f"\ninter.broker.listener.name={protocol}\n" in props, props
        assert f"\nlistener.security.protocol.map=CONTROLLER:{protocol},{protocol}:{protocol}\n" in props, props
    bootstrap = ",".join(cluster.address(n) for n in NODES)
    with pytest.raises(KafkaException):
        AdminClient({"bootstrap.servers": bootstrap, "log_level": 0}).list_topics(timeout=5)
        pytest.fail("a plain anonymous client listed the topics")


PORTS = {name: host for node, host in NODES.items() for name in (node, node + ":controller")}


def test_turning_tls_on_restarts_the_whole_cluster_and_keeps_its_records(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with deployment(tmp_path, PORTS, _plant) as cluster:
        bootstrap = ",".join(cluster.address(n) for n in NODES)
        assert _produce(bootstrap, "line.energy", {}, BEFORE) == []
        _change(cluster, _plant(cluster.ports, tls=True), capsys)

        _speaks(cluster, "SSL")
        client = trusting(ca.ca_cert_file())
        assert read_topic(bootstrap, "line.energy", client, BEFORE, deadline=60) == (BEFORE, set())
        for node in NODES:
            assert _produce(cluster.address(node), "line.energy", client, 5) == [], node
        meta = AdminClient({"bootstrap.servers": bootstrap, "log_level": 0, **client}).list_topics(timeout=15)
        assert all(len(p.isrs) == 3 for p in meta.topics["line.energy"].partitions.values())

        code = cluster.cli("plan", "--detailed-exitcode")
        out = capsys.readouterr().out
        assert code == 0 and "No changes." in out, out


def test_closing_restarts_the_whole_cluster_and_keeps_its_records(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    passwords, files = password_files(tmp_path, ("plc", "mes"))
    with deployment(tmp_path, PORTS, _plant) as cluster:
        bootstrap = ",".join(cluster.address(n) for n in NODES)
        assert _produce(bootstrap, "line.energy", {}, BEFORE) == []
        _change(cluster, _plant(cluster.ports, logins=files), capsys)

        _speaks(cluster, "SASL_PLAINTEXT")
        # the lead sets the new user once in sync; each node enforces it once it applied that
        # metadata record (docs/security.md): a first read may be refused for a moment
        mes = _as("mes", passwords["mes"])
        got: list[tuple[int, set[str]]] = []
        process.wait_until(lambda: (got.append(read_topic(bootstrap, "line.energy", mes, BEFORE, deadline=30)),
                                    got[-1] == (BEFORE, set()))[1], 120.0, 1.0,
                           what="the MES to read the records written before the cluster closed")

        code = cluster.cli("plan", "--detailed-exitcode")
        out = capsys.readouterr().out
        assert code == 0 and "No changes." in out, out
