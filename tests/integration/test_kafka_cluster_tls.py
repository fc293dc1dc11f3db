"""A Kafka cluster with ``pk:tls true`` (issue 13): three KRaft nodes from a plant file, on real
agents and real JVMs, every listener TLS only.

The plant: a cluster ``plant-kafka`` that says ``pk:tls true`` and nothing about anonymous clients
(closed by default), its three combined nodes on 127.0.0.2-4 (each on its own agent, each with a
certificate for its own address from the plant CA); an open Mosquitto on 127.0.0.5 whose
``cell.cam`` a bridge worker carries into the cluster. The PLC publishes ``line.energy``
(replication factor 3, min.insync.replicas 2), the MES reads it and ``cell.cam``; both have a
``pk:secretRef``. One deployment, one apply, shared by the module (three JVMs take a minute to come
up on two cores); the tests run in file order:

1. every node's client, inter-broker and controller listeners are SASL_SSL (the nodes and the
   quorum talk TLS, logged in as plantkg), its key file is 0600; ``plan`` has no change, ``status``
   says TLS for each node (the driver's AdminClient spoke TLS to the lead to create the topics);
2. a plain client, a user without the plant CA (another CA) and an anonymous client with the plant
   CA are refused;
3. the PLC, over SASL_SSL with the plant CA, produces with acks=all through each node; every
   partition has its 3 replicas in sync (replication over TLS); the MES reads what it wrote;
4. the bridge worker (plantkg's principal over SASL_SSL) carries 200 messages from Mosquitto.
"""

from __future__ import annotations

import stat
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from confluent_kafka import KafkaException
from confluent_kafka.admin import AdminClient

from engine.drivers.kafka import tls
from engine.security import ca
from tests.integration.agents import Deployment, deployment
from tests.integration.kafka_clients import password_files, publish_numbered, read_topic
from tests.integration.test_kafka_auth import _produce
from tests.integration.test_kafka_cluster_closed import cluster_nodes

pytestmark = pytest.mark.integration

NODES = {"n1": "127.0.0.2", "n2": "127.0.0.3", "n3": "127.0.0.4"}
MQ = "127.0.0.5"
BRIDGED = 200


@dataclass
class Cluster:
    deployed: Deployment
    passwords: dict[str, str]

    @property
    def bootstrap(self) -> str:
        return ",".join(self.deployed.address(n) for n in NODES)

    def user(self, name: str, ca_file: Path | None = None) -> dict[str, str]:
        """SCRAM over TLS, trusting ``ca_file`` (the plant CA unless told)."""
        return {"security.protocol": "SASL_SSL", "sasl.mechanism": "SCRAM-SHA-512", "sasl.username": name,
                "sasl.password": self.passwords[name], "ssl.ca.location": str(ca_file or ca.ca_cert_file()),
                "ssl.endpoint.identification.algorithm": "https"}


def _plant(ports: dict[str, int], files: dict[str, Path]) -> str:
    nodes = cluster_nodes(ports, NODES)
    return f"""@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix ex: <http://example.org/kafka-cluster-tls#> .
ex:c a pk:Broker ; pk:id "plant-kafka" ; pk:name "plant-kafka" ; pk:brokerType "kafka" ; pk:tls true ;
    pk:minInsyncReplicas 2 ; pk:hasTopic ex:energy , ex:cam .
{nodes}ex:mq a pk:Broker ; pk:id "mq" ; pk:name "cell-mqtt" ; pk:brokerType "mosquitto" ; pk:ip "{MQ}" ;
    pk:port {ports['mq']} ; pk:allowAnonymous true ; pk:hasTopic ex:cam .
ex:energy a pk:Topic ; pk:id "energy" ; pk:name "line.energy" ; pk:partitions 3 ;
    pk:replicationFactor 3 ; pk:minInsyncReplicas 2 .
ex:cam a pk:Topic ; pk:id "cam" ; pk:name "cell.cam" ; pk:qos 1 ; pk:partitions 1 .
ex:camera a pk:Resource ; pk:id "camera" ; pk:name "Camera" ; pk:sendsTo ex:mq ; pk:publishes ex:cam .
ex:plc a pk:Resource ; pk:id "plc" ; pk:name "PLC" ; pk:sendsTo ex:c ; pk:publishes ex:energy ;
    pk:secretRef "file:{files['plc']}" .
ex:mes a pk:Resource ; pk:id "mes" ; pk:name "MES" ; pk:sendsTo ex:c ; pk:subscribes ex:energy , ex:cam ;
    pk:secretRef "file:{files['mes']}" .
"""


@pytest.fixture(scope="module")
def cluster(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cluster]:
    tmp = tmp_path_factory.mktemp("kafka-cluster-tls")
    passwords, files = password_files(tmp, ("plc", "mes"))
    ports = {name: host for node, host in NODES.items() for name in (node, node + ":controller")} | {"mq": MQ}
    with deployment(tmp, ports, lambda picked: _plant(picked, files)) as made:
        yield Cluster(made, passwords)


def test_every_listener_of_every_node_speaks_tls(cluster: Cluster, capsys: pytest.CaptureFixture[str]) -> None:
    for node, host in NODES.items():
        folder = cluster.deployed.fleet.agents[host].state_dir / "brokers" / node
        props = (folder / "server.properties").read_text()
        assert f"listeners=SASL_SSL://{host}:{cluster.deployed.ports[node]},CONTROLLER://" in props, props
        assert "inter.broker.listener.name=SASL_SSL" in props
        assert "listener.security.protocol.map=CONTROLLER:SASL_SSL,SASL_SSL:SASL_SSL" in props
        assert "PLAINTEXT" not in props
        assert stat.S_IMODE((folder / tls.TLS_KEYSTORE_FILE).stat().st_mode) == 0o600
    code = cluster.deployed.cli("plan", "--detailed-exitcode")
    out = capsys.readouterr().out
    assert code == 0 and "No changes." in out, out
    assert cluster.deployed.cli("status") == 0
    out = capsys.readouterr().out
    for node in NODES:
        [row] = [line for line in out.splitlines() if line.startswith(f"{node} ")]
        assert "users (2), TLS" in row, out


def test_plain_anonymous_and_untrusting_clients_are_refused(cluster: Cluster, tmp_path: Path) -> None:
    other = ca.load_or_create_ca(tmp_path / "other-ca")
    plant_ca = {"security.protocol": "SSL", "ssl.ca.location": str(ca.ca_cert_file()),
                "ssl.endpoint.identification.algorithm": "https"}
    plain_login = {k: v for k, v in cluster.user("plc").items() if not k.startswith("ssl.")} | {
        "security.protocol": "SASL_PLAINTEXT"}
    for name, auth in (("plain", {}), ("plain login", plain_login), ("anonymous with the plant CA", plant_ca),
                       ("another CA", cluster.user("plc", other.cert_file))):
        with pytest.raises(KafkaException):
            AdminClient({"bootstrap.servers": cluster.bootstrap, "log_level": 0, **auth}).list_topics(timeout=5)
            pytest.fail(f"{name}: listed the topics")


def test_a_user_with_the_plant_ca_writes_through_every_node_and_reads(cluster: Cluster) -> None:
    plc = cluster.user("plc")
    for node in NODES:
        assert _produce(cluster.deployed.address(node), "line.energy", plc, 5) == [], node
    meta = AdminClient({"bootstrap.servers": cluster.bootstrap, "log_level": 0, **plc}).list_topics(timeout=15)
    assert all(len(p.isrs) == 3 for p in meta.topics["line.energy"].partitions.values())
    assert read_topic(cluster.bootstrap, "line.energy", cluster.user("mes"), 15, deadline=60) == (15, set())


def test_the_bridge_worker_carries_mosquitto_into_the_tls_cluster(cluster: Cluster) -> None:
    publish_numbered(MQ, cluster.deployed.ports["mq"], "cell.cam", BRIDGED)
    got = read_topic(cluster.bootstrap, "cell.cam", cluster.user("mes"), BRIDGED, deadline=90)
    assert got == (BRIDGED, set())
