"""TLS on a Kafka cluster (issue 13), the parts without a broker: ``pk:tls true`` said on the
cluster makes every node TLS (engine.derive), each node's server.properties puts every listener on
TLS (client, inter-broker, controller: open SSL or closed SASL_SSL) with the plant CA as truststore
and endpoint identification on, each node's keystore names its own host, and every plantkg client
of the cluster is told to speak TLS (a bridge end, a context broker's kafka:// notifications). The
cluster itself: tests/integration/test_kafka_cluster_tls.py (closed) and test_kafka_cluster_tls_open.py
(open)."""

from __future__ import annotations

from pathlib import Path

import pytest
from cryptography import x509

from engine.derive import derive
from engine.derived.access import AccessNotSupportedError
from engine.drivers.kafka import tls
from engine.drivers.kafka.driver import KafkaDriver
from engine.drivers.kafka.runtime import KafkaNodeConfig, KafkaTls, render_server_properties
from engine.model import BridgeMechanism
from engine.reasoning.reason import reason
from engine.security.kafka_client import internal_password
from kg.load import load_plant

PASSWORD = internal_password("agent-token-of-the-kafka-machine")
VOTERS = ((1, "127.0.0.2", 9093), (2, "127.0.0.3", 9093), (3, "127.0.0.4", 9093))


def _node(tmp_path: Path, password: str | None, **kw: object) -> str:
    cfg = KafkaNodeConfig("127.0.0.3", 9092, 9093, tmp_path / "data", node_id=2, voters=VOTERS,
                          replication=3, internal_password=password,
                          tls=KafkaTls(tmp_path / "tls-keystore.pem", tmp_path / "tls-ca.pem"), **kw)  # type: ignore[arg-type]
    return render_server_properties(cfg)


@pytest.mark.parametrize(("password", "protocol"), [(None, "SSL"), (PASSWORD, "SASL_SSL")])
def test_every_listener_of_a_tls_cluster_node_speaks_tls(tmp_path: Path, password: str | None, protocol: str) -> None:
    lines = _node(tmp_path, password).splitlines()
    assert "controller.quorum.voters=1@127.0.0.2:9093,2@127.0.0.3:9093,3@127.0.0.4:9093" in lines
    assert f"listeners={protocol}://127.0.0.3:9092,CONTROLLER://127.0.0.3:9093" in lines
    assert f"advertised.listeners={protocol}://127.0.0.3:9092" in lines
    # the quorum (controller) and the inter-broker traffic ride TLS listeners too
    assert f"listener.security.protocol.map=CONTROLLER:{protocol},{protocol}:{protocol}" in lines
    assert f"inter.broker.listener.name={protocol}" in lines
    assert {"ssl.keystore.type=PEM", f"ssl.keystore.location={tmp_path / 'tls-keystore.pem'}",
            "ssl.truststore.type=PEM", f"ssl.truststore.location={tmp_path / 'tls-ca.pem'}",
            "ssl.endpoint.identification.algorithm=https", "ssl.client.auth=none"} <= set(lines)
    assert "PLAINTEXT" not in "\n".join(lines)
    if password is None:
        assert not any(line.startswith(("sasl.", "listener.name.")) for line in lines)
    else:  # the nodes log in to each other (and to the quorum) as plantkg, over TLS
        assert "sasl.mechanism.inter.broker.protocol=PLAIN" in lines
        assert "sasl.mechanism.controller.protocol=PLAIN" in lines
        assert any(line.startswith("listener.name.sasl_ssl.plain.sasl.jaas.config=") for line in lines)
        assert any(line.startswith("listener.name.controller.plain.sasl.jaas.config=") for line in lines)
        assert "super.users=User:plantkg" in lines


def test_a_controller_only_tls_node_listens_for_the_quorum_with_tls(tmp_path: Path) -> None:
    cfg = KafkaNodeConfig("127.0.0.4", 9093, 9093, tmp_path / "data", node_id=3, roles=("controller",),
                          voters=VOTERS, internal_password=PASSWORD,
                          tls=KafkaTls(tmp_path / "tls-keystore.pem", tmp_path / "tls-ca.pem"))
    lines = render_server_properties(cfg).splitlines()
    assert "listeners=CONTROLLER://127.0.0.4:9093" in lines
    assert "listener.security.protocol.map=CONTROLLER:SASL_SSL,SASL_SSL:SASL_SSL" in lines
    assert not any(line.startswith("advertised.listeners") for line in lines)
    assert "ssl.truststore.type=PEM" in lines


TLS_CLUSTER = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <http://example.org/p#> .
:mq a pk:Broker ; pk:id "mq" ; pk:name "mq" ; pk:brokerType "mosquitto" ; pk:ip "127.0.0.5" ; pk:port 1883 .
:plant a pk:Broker ; pk:id "plant" ; pk:name "plant" ; pk:brokerType "kafka" ; pk:tls true .
:k1 a pk:Broker ; pk:id "k1" ; pk:name "k1" ; pk:brokerType "kafka" ; pk:ip "127.0.0.2" ; pk:port 9092 ;
    pk:nodeOf :plant ; pk:nodeId 1 ; pk:kafkaRole "broker" , "controller" ; pk:controllerPort 9093 .
:k2 a pk:Broker ; pk:id "k2" ; pk:name "k2" ; pk:brokerType "kafka" ; pk:ip "127.0.0.3" ; pk:port 9092 ;
    pk:nodeOf :plant ; pk:nodeId 2 ; pk:kafkaRole "broker" , "controller" ; pk:controllerPort 9093 .
:k3 a pk:Broker ; pk:id "k3" ; pk:name "k3" ; pk:brokerType "kafka" ; pk:ip "127.0.0.4" ; pk:port 9093 ;
    pk:nodeOf :plant ; pk:nodeId 3 ; pk:kafkaRole "controller" .
:cb a pk:Broker ; pk:id "cb" ; pk:name "cb" ; pk:brokerType "ngsi-v2" ; pk:ip "127.0.0.6" ; pk:port 1026 .
:pos a pk:Topic ; pk:id "pos" ; pk:name "line.position" .
:robot a pk:Resource ; pk:id "robot" ; pk:name "robot" ; pk:sendsTo :mq ; pk:publishes :pos .
:line a pk:Resource ; pk:id "line" ; pk:name "line" ; pk:sendsTo :plant ; pk:subscribes :pos .
:state a pk:Topic ; pk:id "state" ; pk:name "cell/state" .
:twin a pk:Resource ; pk:id "twin" ; pk:name "twin" ; pk:sendsTo :cb ; pk:publishes :state .
"""


def _derived(tmp_path: Path, text: str):  # type: ignore[no-untyped-def]
    path = tmp_path / "plant.ttl"
    path.write_text(text, encoding="utf-8")
    plant = load_plant([path])
    reason(plant, engine="fast")
    return derive(plant)


def test_tls_said_on_the_cluster_reaches_every_node_and_every_plantkg_client(tmp_path: Path) -> None:
    desired = _derived(tmp_path, TLS_CLUSTER)
    specs = {b.id: b for b in desired.brokers}
    assert all(specs[n].tls and specs[n].allow_anonymous is False for n in ("k1", "k2", "k3"))
    assert not specs["mq"].tls
    # the context broker's kafka:// notifications: TLS and plantkg's login on the broker nodes
    assert specs["cb"].tls_kafkas == ("127.0.0.2:9092", "127.0.0.3:9092")
    assert specs["cb"].closed_kafkas == ("127.0.0.2:9092", "127.0.0.3:9092")
    [bridge] = [b for b in desired.bridges if b.mechanism is BridgeMechanism.WORKER]
    end = bridge.remote if bridge.remote.kind == "kafka" else bridge.local
    assert end.tls and end.closed and end.bootstrap == ("127.0.0.2:9092", "127.0.0.3:9092")


def test_each_node_gets_a_certificate_for_its_own_host(tmp_path: Path) -> None:
    specs = {b.id: b for b in _derived(tmp_path, TLS_CLUSTER).brokers}
    for name, host in (("k2", "127.0.0.3"), ("k3", "127.0.0.4")):
        broker_dir = tmp_path / name
        files = KafkaDriver().render_config(specs[name], broker_dir)
        cert_pem, _key = tls.split_keystore(files[tls.TLS_KEYSTORE_FILE])
        san = x509.load_pem_x509_certificate(cert_pem or b"").extensions.get_extension_for_class(
            x509.SubjectAlternativeName).value
        assert [str(ip) for ip in san.get_values_for_type(x509.IPAddress)] == [host]
        assert f"ssl.truststore.location={broker_dir / tls.TLS_CA_FILE}" in files["server.properties"]


def test_tls_said_on_one_node_only_is_refused(tmp_path: Path) -> None:
    text = TLS_CLUSTER.replace('pk:brokerType "kafka" ; pk:tls true .', 'pk:brokerType "kafka" .')
    text += ':k1 pk:tls true .\n'
    with pytest.raises(AccessNotSupportedError, match="its nodes k1 say pk:tls true but not the cluster"):
        _derived(tmp_path, text)
