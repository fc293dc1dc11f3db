"""An *open* Kafka cluster with ``pk:tls true`` (issue 13): three KRaft nodes from a plant file,
on real agents and real JVMs, every listener SSL (TLS, no login). test_kafka_cluster_tls.py runs
the closed one; this is the other half of the driver's choice (``SSL`` instead of ``SASL_SSL``).

The plant: a cluster ``plant-kafka`` that says ``pk:tls true`` and ``pk:allowAnonymous true``, its
three combined nodes on 127.0.0.2-4 (each on its own agent, with a plant-CA certificate for its own
address); the PLC publishes ``line.energy`` (replication factor 3, min.insync.replicas 2), the MES
reads it, neither with a ``pk:secretRef``. One deployment, one apply, shared by the module (three
JVMs take a minute to come up on two cores; run this file alone with ``-n 1``):

1. every node's client, inter-broker and controller listeners are SSL, nothing plain, no SASL;
   its key file is 0600; ``status`` says ``open, TLS`` for each node; a second ``plan`` is empty;
2. a plain client and a client trusting another CA are refused;
3. a client trusting the plant CA (no login) produces with acks=all through each node, every
   partition has its 3 replicas in sync (replication over TLS), and reads it back.
"""

from __future__ import annotations

import stat
from collections.abc import Iterator
from pathlib import Path

import pytest
from confluent_kafka import KafkaException
from confluent_kafka.admin import AdminClient

from engine.drivers.kafka import tls
from engine.security import ca
from tests.integration.agents import Deployment, deployment
from tests.integration.kafka_clients import read_topic
from tests.integration.test_kafka_auth import _produce
from tests.integration.test_kafka_cluster_closed import cluster_nodes

pytestmark = pytest.mark.integration

NODES = {"n1": "127.0.0.2", "n2": "127.0.0.3", "n3": "127.0.0.4"}


def trusting(ca_file: Path) -> dict[str, str]:
    """A client without login over TLS, trusting ``ca_file`` and checking the node's address."""
    return {"security.protocol": "SSL", "ssl.ca.location": str(ca_file),
            "ssl.endpoint.identification.algorithm": "https"}


def _plant(ports: dict[str, int]) -> str:
    nodes = cluster_nodes(ports, NODES)
    return f"""@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix ex: <http://example.org/kafka-cluster-tls-open#> .
ex:c a pk:Broker ; pk:id "plant-kafka" ; pk:name "plant-kafka" ; pk:brokerType "kafka" ; pk:tls true ;
    pk:allowAnonymous true ; pk:minInsyncReplicas 2 ; pk:hasTopic ex:energy .
{nodes}ex:energy a pk:Topic ; pk:id "energy" ; pk:name "line.energy" ; pk:partitions 3 ;
    pk:replicationFactor 3 ; pk:minInsyncReplicas 2 .
ex:plc a pk:Resource ; pk:id "plc" ; pk:name "PLC" ; pk:sendsTo ex:c ; pk:publishes ex:energy .
ex:mes a pk:Resource ; pk:id "mes" ; pk:name "MES" ; pk:sendsTo ex:c ; pk:subscribes ex:energy .
"""


@pytest.fixture(scope="module")
def cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployment]:
    tmp = tmp_path_factory.mktemp("kafka-cluster-tls-open")
    ports = {name: host for node, host in NODES.items() for name in (node, node + ":controller")}
    with deployment(tmp, ports, _plant) as made:
        yield made


def bootstrap(cluster: Deployment) -> str:
    return ",".join(cluster.address(n) for n in NODES)


def test_every_listener_of_every_node_speaks_tls_without_login(cluster: Deployment,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    for node, host in NODES.items():
        folder = cluster.fleet.agents[host].state_dir / "brokers" / node
        props = (folder / "server.properties").read_text()
        assert f"listeners=SSL://{host}:{cluster.ports[node]},CONTROLLER://" in props, props
        assert "inter.broker.listener.name=SSL" in props
        assert "listener.security.protocol.map=CONTROLLER:SSL,SSL:SSL" in props
        assert "PLAINTEXT" not in props and "SASL" not in props, props
        assert stat.S_IMODE((folder / tls.TLS_KEYSTORE_FILE).stat().st_mode) == 0o600
    assert cluster.cli("status") == 0
    out = capsys.readouterr().out
    for node in NODES:
        [row] = [line for line in out.splitlines() if line.startswith(f"{node} ")]
        assert "open, TLS" in row, out
    code = cluster.cli("plan", "--detailed-exitcode")
    out = capsys.readouterr().out
    assert code == 0 and "No changes." in out, out


def test_plain_and_untrusting_clients_are_refused(cluster: Deployment, tmp_path: Path) -> None:
    other = ca.load_or_create_ca(tmp_path / "other-ca")
    for name, auth in (("plain", {}), ("another CA", trusting(other.cert_file))):
        with pytest.raises(KafkaException):
            AdminClient({"bootstrap.servers": bootstrap(cluster), "log_level": 0, **auth}).list_topics(timeout=5)
            pytest.fail(f"{name}: listed the topics")


def test_a_client_trusting_the_plant_ca_writes_through_every_node_and_reads(cluster: Deployment) -> None:
    client = trusting(ca.ca_cert_file())
    for node in NODES:
        assert _produce(cluster.address(node), "line.energy", client, 5) == [], node
    meta = AdminClient({"bootstrap.servers": bootstrap(cluster), "log_level": 0, **client}).list_topics(timeout=15)
    assert all(len(p.isrs) == 3 for p in meta.topics["line.energy"].partitions.values())
    assert read_topic(bootstrap(cluster), "line.energy", client, 15, deadline=60) == (15, set())
