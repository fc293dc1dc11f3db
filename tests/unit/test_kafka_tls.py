"""TLS for a Kafka broker of its own (issue 13), the parts without a broker: the listeners and ssl
lines of server.properties, the PEM keystore the driver renders from the plant CA (kept while
current, 0600 when the agent writes it), the librdkafka settings of plantkg's clients and of a
bridge worker and a MirrorMaker 2, and what is refused before anything runs (a cluster whose nodes
disagree). A cluster's TLS nodes: tests/unit/test_kafka_cluster_tls.py.
The broker itself: tests/integration/test_kafka_tls.py."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from cryptography import x509

from engine.derived.access import AccessNotSupportedError, check_kafka_tls_supported
from engine.security import kafka_client
from engine.security.kafka_client import internal_password as kafka_internal_password
from engine.agent.workers import mirror_config, worker_config
from engine.bridge_worker.config import WorkerConfig
from engine.drivers.kafka import tls
from engine.drivers.kafka.driver import CONTROLLER_PORT_FILE, KafkaDriver
from engine.drivers.kafka.mirror import render_mm2_properties
from engine.drivers.kafka.mirror_worker import MirrorWorkerConfig
from engine.drivers.kafka.runtime import KafkaNodeConfig, KafkaTls, render_server_properties
from engine.errors import ConfigValueError
from engine.model import (
    BridgeDirection,
    BridgeEnd,
    BridgeMechanism,
    BridgeRoute,
    BridgeSpec,
    BrokerSpec,
    DesiredState,
    KafkaNode,
    ObservedState,
)
from engine.plan import plan
from engine.security import ca

PASSWORD = kafka_internal_password("agent-token-of-the-kafka-machine")


def _tls(tmp_path: Path) -> KafkaTls:
    return KafkaTls(tmp_path / "tls-keystore.pem", tmp_path / "tls-ca.pem")


@pytest.mark.parametrize(("password", "protocol"), [(None, "SSL"), (PASSWORD, "SASL_SSL")])
def test_a_tls_kafka_listens_with_tls_only(tmp_path: Path, password: str | None, protocol: str) -> None:
    text = render_server_properties(KafkaNodeConfig("127.0.0.3", 9092, 9093, tmp_path / "data",
                                                    internal_password=password, tls=_tls(tmp_path)))
    lines = text.splitlines()
    assert f"listeners={protocol}://127.0.0.3:9092,CONTROLLER://127.0.0.3:9093" in lines
    assert f"advertised.listeners={protocol}://127.0.0.3:9092" in lines
    assert f"listener.security.protocol.map=CONTROLLER:{protocol},{protocol}:{protocol}" in lines
    assert "ssl.keystore.type=PEM" in lines and "ssl.truststore.type=PEM" in lines
    assert f"ssl.keystore.location={tmp_path / 'tls-keystore.pem'}" in lines
    assert f"ssl.truststore.location={tmp_path / 'tls-ca.pem'}" in lines
    assert "PLAINTEXT" not in text
    if password is not None:  # the JAAS lines follow the listener's name
        assert any(line.startswith("listener.name.sasl_ssl.plain.sasl.jaas.config=") for line in lines)
    plain = render_server_properties(KafkaNodeConfig("127.0.0.3", 9092, 9093, tmp_path / "data"))
    assert "ssl." not in plain and "SSL" not in plain


def test_a_path_that_breaks_the_file_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigValueError, match="tls.keystore"):
        KafkaTls(Path("/tmp/a\nssl.client.auth=none"), tmp_path / "ca.pem")


def _spec(host: str = "127.0.0.3", **kw: object) -> BrokerSpec:
    return BrokerSpec("kf", "urn:kf", "kf", "kafka", host, 9092, **kw)  # type: ignore[arg-type]


def _render(tmp_path: Path, spec: BrokerSpec) -> dict[str, str]:
    (tmp_path / CONTROLLER_PORT_FILE).write_text("9093\n", encoding="ascii")
    return KafkaDriver().render_config(spec, tmp_path)


def test_the_driver_renders_a_keystore_from_the_plant_ca_and_keeps_it(tmp_path: Path) -> None:
    spec = _spec(tls=True)
    files = _render(tmp_path, spec)
    authority = ca.load_ca(ca.ca_dir())
    assert files[tls.TLS_CA_FILE].encode() == ca.ca_pem(authority)
    cert_pem, key_pem = tls.split_keystore(files[tls.TLS_KEYSTORE_FILE])
    assert key_pem is not None and key_pem.startswith(b"-----BEGIN PRIVATE KEY-----")  # PKCS#8, unencrypted
    cert = x509.load_pem_x509_certificate(cert_pem or b"")
    cert.verify_directly_issued_by(authority.cert)
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert [str(ip) for ip in san.get_values_for_type(x509.IPAddress)] == ["127.0.0.3"]
    assert "ssl.keystore.type=PEM" in files["server.properties"]
    for name, text in files.items():
        (tmp_path / name).write_text(text, encoding="ascii")
    assert _render(tmp_path, spec) == files  # current: the same files, no restart
    assert KafkaDriver().tls_renewal(spec, tmp_path) is None
    moved = _spec(tls=True, host="127.0.0.4")
    assert KafkaDriver().tls_renewal(moved, tmp_path) == "for other addresses"
    assert _render(tmp_path, moved)[tls.TLS_KEYSTORE_FILE] != files[tls.TLS_KEYSTORE_FILE]


def test_a_plain_kafka_renders_and_restarts_as_before(tmp_path: Path) -> None:
    files = _render(tmp_path, _spec())
    assert set(files) == {"server.properties"}
    assert "tls" not in KafkaDriver().essence(_spec())
    assert KafkaDriver().essence(_spec(tls=True))["tls"] is True
    assert KafkaDriver().tls_renewal(_spec(), tmp_path) is None


def test_the_plan_shows_tls_on_a_kafka() -> None:
    desired = DesiredState((_spec(tls=True),), (), ())
    [change] = plan(desired, ObservedState()).changes
    assert change.after is not None and change.after["tls"] is True
    [change] = plan(DesiredState((_spec(),), (), ()), ObservedState()).changes
    assert change.after is not None and "tls" not in change.after


def test_plantkgs_clients_trust_the_plant_ca_only() -> None:
    assert kafka_client.client_settings(False, True, Path("/x/ca.pem")) == {
        "security.protocol": "ssl", "ssl.ca.location": "/x/ca.pem",
        "ssl.endpoint.identification.algorithm": "https"}
    assert kafka_client.client_settings(True, True, Path("/x/ca.pem"))["security.protocol"] == "sasl_ssl"


def _bridge(kafka_tls: bool, mechanism: BridgeMechanism = BridgeMechanism.WORKER) -> BridgeSpec:
    local = BridgeEnd("mq", "mosquitto", "127.0.0.2", 1883)
    if mechanism is BridgeMechanism.MIRROR:
        local = BridgeEnd("k0", "kafka", "127.0.0.2", 9092)
    return BridgeSpec(local, BridgeEnd("kf", "kafka", "127.0.0.3", 9092, tls=kafka_tls), mechanism,
                      (BridgeRoute("cell.cam", BridgeDirection.IN if mechanism is BridgeMechanism.MIRROR
                                   else BridgeDirection.OUT),))


def test_a_bridge_worker_speaks_tls_to_a_tls_kafka(tmp_path: Path) -> None:
    cfg = worker_config(_bridge(True), tmp_path)
    assert cfg.kafka_ca_file == ca.ca_cert_file()
    assert cfg.kafka_auth() == {"security.protocol": "SSL", "ssl.ca.location": str(ca.ca_cert_file()),
                                "ssl.endpoint.identification.algorithm": "https"}
    assert WorkerConfig.from_json(cfg.to_json()) == cfg
    secret = tmp_path / "remote.token"
    secret.write_text(PASSWORD, encoding="utf-8")
    closed = WorkerConfig.from_json(json.dumps({**json.loads(cfg.to_json()), "kafka_password_file": str(secret)}))
    assert closed.kafka_auth()["security.protocol"] == "SASL_SSL"
    assert closed.kafka_auth()["sasl.password"] == PASSWORD
    plain = worker_config(_bridge(False), tmp_path)
    assert plain.kafka_auth() == {} and "kafka_ca_file" not in json.loads(plain.to_json())
    with pytest.raises(ConfigValueError, match="kafka_ca_file"):
        WorkerConfig.from_json(json.dumps({**json.loads(cfg.to_json()), "kafka_ca_file": "relative/ca.pem"}))


def test_a_cluster_whose_nodes_disagree_on_tls_is_refused() -> None:
    def node(node_id: int, **kw: object) -> BrokerSpec:
        kafka = KafkaNode(cluster="c", node_id=node_id, roles=("broker", "controller"), controller_port=9093,
                          voters=(), cluster_id="AAAAAAAAAAAAAAAAAAAAAA", replication=1)
        return BrokerSpec(f"k{node_id}", f"urn:k{node_id}", f"k{node_id}", "kafka", f"127.0.0.{node_id}", 9092,
                          kafka=kafka, **kw)  # type: ignore[arg-type]
    with pytest.raises(AccessNotSupportedError, match="cluster 'c': its nodes k1 say pk:tls true but not"):
        check_kafka_tls_supported([node(1, tls=True), node(2)])
    check_kafka_tls_supported([node(1, tls=True), node(2, tls=True)])  # the cluster said it
    check_kafka_tls_supported([node(1), node(2), _spec(tls=True)])  # a TLS broker of its own beside a plain cluster


def test_a_mirror_speaks_tls_to_a_tls_kafka_end(tmp_path: Path) -> None:
    cfg = mirror_config(_bridge(True, BridgeMechanism.MIRROR), tmp_path)
    assert cfg.ca_file == ca.ca_cert_file()
    assert (cfg.mirror.source_tls, cfg.mirror.target_tls) == (True, False)  # kf is the source
    assert MirrorWorkerConfig.from_json(cfg.to_json()) == cfg
    lines = render_mm2_properties(cfg.mirror, None, cfg.ca_file).splitlines()
    assert {"source.security.protocol=SSL", "source.ssl.truststore.type=PEM",
            f"source.ssl.truststore.location={ca.ca_cert_file()}",
            "source.ssl.endpoint.identification.algorithm=https"} <= set(lines)
    assert not any(line.startswith("target.s") for line in lines)  # the plain end: no TLS
    plain = mirror_config(_bridge(False, BridgeMechanism.MIRROR), tmp_path)
    assert plain.ca_file is None and "ca_file" not in plain.to_json()
    with pytest.raises(ConfigValueError, match="needs the plant CA"):
        render_mm2_properties(cfg.mirror)
