"""Drivers: golden renderings, refusal of unsafe values, essences, the registry, MQTT health.

Golden files live in tests/unit/golden/drivers/ with ``@BROKER_DIR@`` for the broker folder;
``PLANTKG_UPDATE_GOLDEN=1 pytest tests/unit/test_drivers.py`` rewrites them (review the diff).
"""

from __future__ import annotations

import os
import socket
import subprocess
from importlib.metadata import EntryPoint
from pathlib import Path

import pytest

from engine import netutil, parts, process
from engine.drivers import registry as registry_module
from engine.drivers.base import Driver, Waking, config_hash
from engine.drivers.kafka.driver import KafkaDriver, check_kafka_topic_name, read_controller_port
from engine.drivers.mosquitto.driver import MosquittoDriver, check_mqtt_topic_name
from engine.drivers.registry import DriverRegistry
from engine.errors import (
    ConfigValueError,
    EngineError,
    JavaMissingError,
    KafkaMissingError,
    MosquittoMissingError,
    UnknownDriverError,
)
from engine.model import (
    BridgeDirection,
    BridgeEnd,
    BridgeMechanism,
    BridgeRoute,
    BridgeSpec,
    BrokerSpec,
    ObservedTopic,
    TopicSpec,
)

GOLDEN = Path(__file__).parent / "golden" / "drivers"


def mqtt_spec(**changes) -> BrokerSpec:
    values = dict(id="m1", iri="https://example.org/plant#m1", name="Cell MQTT", kind="mosquitto",
                  host="127.0.0.2", port=18830)
    return BrokerSpec(**{**values, **changes})


def kafka_spec(**changes) -> BrokerSpec:
    values = dict(id="k1", iri="https://example.org/plant#k1", name="Cell Kafka", kind="kafka",
                  host="127.0.0.3", port=19092)
    return BrokerSpec(**{**values, **changes})


def check_golden(name: str, text: str, broker_dir: Path) -> None:
    rendered = text.replace(str(broker_dir), "@BROKER_DIR@")
    path = GOLDEN / name
    if os.environ.get("PLANTKG_UPDATE_GOLDEN"):
        path.write_text(rendered, encoding="utf-8")
    assert rendered == path.read_text(encoding="utf-8")


@pytest.fixture
def kafka_dir(tmp_path: Path) -> Path:
    (tmp_path / "controller.port").write_text("19093\n", encoding="ascii")
    return tmp_path


# --- golden renderings ---------------------------------------------------------------------

def test_mosquitto_golden(tmp_path: Path) -> None:
    files = MosquittoDriver(run_as=None).render_config(mqtt_spec(), tmp_path)
    assert list(files) == ["mosquitto.conf"]
    check_golden("mosquitto.conf", files["mosquitto.conf"], tmp_path)


def two_way_bridge(**changes) -> BridgeSpec:
    values = dict(
        local=BridgeEnd("m1", "mosquitto", "127.0.0.2", 18830),
        remote=BridgeEnd("m2", "mosquitto", "127.0.0.4", 18831),
        mechanism=BridgeMechanism.MOSQUITTO,
        routes=(BridgeRoute("cell/robot/pose", BridgeDirection.OUT, 1),
                BridgeRoute("cell/robot/command", BridgeDirection.IN, 2),
                BridgeRoute("cell.alarms", BridgeDirection.BOTH, 0)))
    return BridgeSpec(**{**values, **changes})


def test_mosquitto_golden_with_a_bridge(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """With a fixed principal key, so the bridge's remote password (derived from it) is fixed."""
    key = tmp_path / "key"
    key.write_text("11" * 32 + "\n", encoding="ascii")
    key.chmod(0o600)
    monkeypatch.setenv("PLANTKG_PRINCIPAL_KEY", str(key))
    files = MosquittoDriver(run_as=None).render_config(mqtt_spec(), tmp_path, (two_way_bridge(),))
    check_golden("mosquitto-bridge.conf", files["mosquitto.conf"], tmp_path)


@pytest.mark.parametrize(("kind", "flag"), [("mosquitto", "try_private true"), ("othermq", "try_private false")])
def test_mosquitto_sets_its_bridge_flag_only_towards_a_mosquitto(tmp_path: Path, kind: str, flag: str) -> None:
    """The flag (protocol level | 0x80) is Mosquitto's own: another MQTT broker may refuse it."""
    remote = BridgeEnd("m2", kind, "127.0.0.3", 18831)
    conf = MosquittoDriver(run_as=None).render_config(mqtt_spec(), tmp_path, (two_way_bridge(remote=remote),))
    assert flag in conf["mosquitto.conf"].splitlines()


@pytest.mark.parametrize("bridge, field", [
    (two_way_bridge(local=BridgeEnd("other", "mosquitto", "127.0.0.9", 1883)), "bridges"),
    (two_way_bridge(mechanism=BridgeMechanism.WORKER), "bridges"),
    (two_way_bridge(remote=BridgeEnd("m2", "mosquitto", "::1", 18831)), "remote_host"),
    (two_way_bridge(routes=(BridgeRoute("a b", BridgeDirection.OUT),)), "pattern"),
    (two_way_bridge(routes=(BridgeRoute("a/+", BridgeDirection.OUT),)), "pattern"),
    (two_way_bridge(routes=(BridgeRoute('a"', BridgeDirection.OUT),)), "pattern"),
    (two_way_bridge(routes=(BridgeRoute("a\ntopic x out", BridgeDirection.OUT),)), "pattern"),
    (two_way_bridge(routes=()), "topics"),
])
def test_mosquitto_refuses_bridges_it_cannot_render(tmp_path: Path, bridge: BridgeSpec, field: str) -> None:
    with pytest.raises(ConfigValueError) as caught:
        MosquittoDriver(run_as=None).render_config(mqtt_spec(), tmp_path, (bridge,))
    assert caught.value.field == field


def test_kafka_carries_no_native_bridge(kafka_dir: Path) -> None:
    bridge = two_way_bridge(local=BridgeEnd("k1", "kafka", "127.0.0.3", 19092))
    with pytest.raises(ConfigValueError, match="carries no native bridge"):
        KafkaDriver().render_config(kafka_spec(), kafka_dir, (bridge,))


def test_mosquitto_golden_run_as(tmp_path: Path) -> None:
    files = MosquittoDriver(run_as="plantkg").render_config(mqtt_spec(), tmp_path)
    check_golden("mosquitto-run-as.conf", files["mosquitto.conf"], tmp_path)


def test_kafka_golden(kafka_dir: Path) -> None:
    files = KafkaDriver().render_config(kafka_spec(), kafka_dir)
    assert list(files) == ["server.properties"]
    check_golden("kafka-server.properties", files["server.properties"], kafka_dir)


def test_kafka_golden_ipv6(kafka_dir: Path) -> None:
    files = KafkaDriver().render_config(kafka_spec(id="k6", host="::1"), kafka_dir)
    check_golden("kafka-server-ipv6.properties", files["server.properties"], kafka_dir)


def test_rendering_is_pure(kafka_dir: Path) -> None:
    driver = KafkaDriver()
    before = sorted(p.name for p in kafka_dir.iterdir())
    first = driver.render_config(kafka_spec(), kafka_dir)
    assert driver.render_config(kafka_spec(), kafka_dir) == first
    assert sorted(p.name for p in kafka_dir.iterdir()) == before
    assert config_hash(first) == config_hash(dict(first))
    assert config_hash(first) != config_hash({"server.properties": first["server.properties"] + "#"})


def test_kafka_render_needs_the_stored_controller_port(tmp_path: Path) -> None:
    with pytest.raises(EngineError, match="controller.port is missing"):
        KafkaDriver().render_config(kafka_spec(), tmp_path)
    (tmp_path / "controller.port").write_text("9093\nx", encoding="ascii")
    with pytest.raises(ConfigValueError) as info:
        read_controller_port(tmp_path)
    assert info.value.field == "controller_port"


def test_commands(tmp_path: Path) -> None:
    argv = MosquittoDriver(binary=Path("/usr/sbin/mosquitto")).command(mqtt_spec(), tmp_path)
    assert argv == ["/usr/sbin/mosquitto", "-c", str(tmp_path / "mosquitto.conf")]
    try:
        kafka_argv = KafkaDriver(heap="384m").command(kafka_spec(), tmp_path)
    except EngineError as exc:  # pragma: no cover - setup not run
        pytest.skip(str(exc))
    assert "-Xmx384m" in kafka_argv
    assert kafka_argv[-2:] == ["kafka.Kafka", str(tmp_path / "server.properties")]
    assert f"-Dkafka.logs.dir={tmp_path / 'logs'}" in kafka_argv


# --- refusals ------------------------------------------------------------------------------

@pytest.mark.parametrize(("changes", "field"), [
    ({"port": 0}, "port"),
    ({"port": 65536}, "port"),
    ({"port": True}, "port"),
    ({"port": "1883"}, "port"),
    ({"host": "broker.local"}, "host"),
    ({"host": "127.0.0.1\nlistener 1 0.0.0.0"}, "host"),
])
@pytest.mark.parametrize("driver", [MosquittoDriver(run_as=None), KafkaDriver()], ids=["mosquitto", "kafka"])
def test_bad_broker_values_are_refused(driver: Driver, changes: dict, field: str) -> None:
    spec = (mqtt_spec if driver.kind == "mosquitto" else kafka_spec)(**changes)
    with pytest.raises(ConfigValueError) as info:
        driver.validate(spec)
    assert info.value.field == field


def test_kafka_refuses_a_wildcard_host() -> None:
    with pytest.raises(ConfigValueError) as info:
        KafkaDriver().validate(kafka_spec(host="0.0.0.0"))
    assert info.value.field == "advertised_host"
    MosquittoDriver(run_as=None).validate(mqtt_spec(host="0.0.0.0"))  # Mosquitto may listen there


@pytest.mark.parametrize("folder", ["relative/dir", "/state/bro\nkers/m1", "/state/a\\b"])
def test_an_unsafe_broker_folder_is_refused(folder: str) -> None:
    with pytest.raises(ConfigValueError):
        MosquittoDriver(run_as=None).render_config(mqtt_spec(), Path(folder))


def test_a_bad_run_as_user_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ConfigValueError):
        MosquittoDriver(run_as="root\nlistener 1").render_config(mqtt_spec(), tmp_path)


@pytest.mark.parametrize("name", ["a/+/b", "a/#", "line\nbreak", "nul\0", "", "x" * 65_536,
                                  "sep\u2028arator", "c1\u0085"])
def test_bad_mqtt_topic_names(name: str) -> None:
    with pytest.raises(ConfigValueError) as info:
        check_mqtt_topic_name(name)
    assert info.value.field == "name"


@pytest.mark.parametrize("name", ["/factory//cell 1/ü", "$custom", "a" * 1000])
def test_good_mqtt_topic_names(name: str) -> None:
    assert check_mqtt_topic_name(name) == name


@pytest.mark.parametrize("name", ["a/b", "has space", ".", "..", "x" * 250, "", "ü", "a\n"])
def test_bad_kafka_topic_names(name: str) -> None:
    with pytest.raises(ConfigValueError):
        check_kafka_topic_name(name)


def test_good_kafka_topic_name() -> None:
    assert check_kafka_topic_name("robot.abb-irb120_position") == "robot.abb-irb120_position"


def test_mqtt_topic_settings() -> None:
    driver = MosquittoDriver(run_as=None)
    topic = TopicSpec(broker_id="m1", name="cell/robot/pos", iri="urn:t", qos=1, retain=True)
    assert driver.ensure_topic(mqtt_spec(), topic) == ObservedTopic("cell/robot/pos", qos=1, retain=True)
    assert driver.observe_topics(mqtt_spec()) == []


@pytest.mark.parametrize(("changes", "field"), [
    ({"partitions": 3}, "partitions"),       # a Kafka setting on an MQTT topic
    ({"retention_ms": 1000}, "retention_ms"),
    ({"qos": 3}, "qos"),
    ({"qos": True}, "qos"),
    ({"retain": 1}, "retain"),
])
def test_bad_mqtt_topic_settings(changes: dict, field: str) -> None:
    topic = TopicSpec(broker_id="m1", name="t", iri="urn:t", **changes)
    with pytest.raises(ConfigValueError) as info:
        MosquittoDriver(run_as=None).ensure_topic(mqtt_spec(), topic)
    assert info.value.field == field


@pytest.mark.parametrize(("changes", "field"), [
    ({"qos": 1}, "qos"),                     # an MQTT setting on a Kafka topic
    ({"partitions": 0}, "partitions"),
    ({"partitions": 10_001}, "partitions"),
    ({"replication_factor": 0}, "replication_factor"),
    ({"retention_ms": -2}, "retention_ms"),
])
def test_bad_kafka_topic_settings_are_refused_before_any_connection(changes: dict, field: str) -> None:
    topic = TopicSpec(broker_id="k1", name="t", iri="urn:t", **changes)
    # Port 1 on loopback: if the driver tried to connect, the test would see another error.
    with pytest.raises(ConfigValueError) as info:
        KafkaDriver().ensure_topic(kafka_spec(port=1), topic)
    assert info.value.field == field


# --- essence -------------------------------------------------------------------------------

@pytest.mark.parametrize("driver", [MosquittoDriver(run_as=None), KafkaDriver()], ids=["mosquitto", "kafka"])
def test_essence_ignores_names_and_follows_the_listener(driver: Driver) -> None:
    spec = (mqtt_spec if driver.kind == "mosquitto" else kafka_spec)()
    renamed = BrokerSpec(**{**spec.__dict__, "name": "Other", "iri": "urn:other"})
    moved = BrokerSpec(**{**spec.__dict__, "port": spec.port + 1})
    assert driver.essence(renamed) == driver.essence(spec)
    assert driver.essence(moved) != driver.essence(spec)
    # Mosquitto restarts for its save policy too (pk:persistEvery), its users and TLS; Kafka ignores them
    extra = {"persist_every", "closed", "users", "tls"} if driver.kind == "mosquitto" else set()
    assert set(driver.essence(spec)) == {"kind", "host", "port"} | extra


# --- registry ------------------------------------------------------------------------------

def test_registry_from_entry_points() -> None:
    registry = DriverRegistry.from_entry_points()
    # The built-in drivers; an installed plugin package (plugins/) may add its own.
    assert {"kafka", "mosquitto", "ngsi-v2"} <= set(registry.kinds()), registry.errors
    assert not registry.errors
    assert isinstance(registry.get("kafka"), KafkaDriver)
    assert isinstance(registry.get("mosquitto"), Driver)
    assert "mosquitto" in registry and "activemq" not in registry
    with pytest.raises(UnknownDriverError, match="installed: kafka, mosquitto, ngsi-v2"):
        registry.get("activemq")


def test_registries_are_independent() -> None:
    only = DriverRegistry([MosquittoDriver(run_as=None)])
    assert only.kinds() == ["mosquitto"]
    assert {"kafka", "mosquitto", "ngsi-v2"} <= set(DriverRegistry.from_entry_points().kinds())
    with pytest.raises(ValueError, match="two drivers"):
        DriverRegistry([MosquittoDriver(), MosquittoDriver()])
    with pytest.raises(TypeError):
        DriverRegistry([object()])  # type: ignore[list-item]


def test_a_broken_driver_entry_point_is_reported_not_fatal(monkeypatch: pytest.MonkeyPatch) -> None:
    group = registry_module.ENTRY_POINT_GROUP
    fake = [
        EntryPoint("mosquitto", "engine.drivers.mosquitto.driver:MosquittoDriver", group),
        EntryPoint("zeromq", "plantkg_zeromq_missing.driver:ZmqDriver", group),
        EntryPoint("kafka", "engine.drivers.mosquitto.driver:MosquittoDriver", group),  # wrong kind
    ]
    monkeypatch.setattr(registry_module, "entry_points", lambda group: fake)
    registry = DriverRegistry.from_entry_points()
    assert registry.kinds() == ["mosquitto"]
    assert "ModuleNotFoundError" in registry.errors["zeromq"]
    assert "not the entry-point name" in registry.errors["kafka"]


# --- MQTT health (a real Mosquitto) --------------------------------------------------------

def test_mosquitto_health_is_an_mqtt_connect(tmp_path: Path) -> None:
    driver = MosquittoDriver()
    spec = mqtt_spec(host="127.0.0.1", port=netutil.free_port())
    assert driver.health(spec, 0.5) is False  # nothing listens
    (tmp_path / "logs").mkdir()
    for name, text in driver.render_config(spec, tmp_path).items():
        (tmp_path / name).write_text(text, encoding="utf-8")
    child = process.spawn(driver.command(spec, tmp_path), log_dir=tmp_path / "logs", name="mosquitto")
    try:
        process.wait_until(lambda: driver.health(spec, 1.0), 10.0, 0.01, child=child,
                           what="a CONNACK")
        fds = len(os.listdir("/proc/self/fd"))
        for _ in range(20):
            assert driver.health(spec, 1.0)
        assert len(os.listdir("/proc/self/fd")) <= fds + 2, "health checks leak sockets"
    finally:
        process.stop(child, grace=5.0)
    assert "plantkg-health-" in (tmp_path / "logs" / "mosquitto.log").read_text(encoding="utf-8")


def test_a_plain_tcp_listener_is_not_healthy() -> None:
    with socket.create_server(("127.0.0.1", 0)) as server:
        spec = mqtt_spec(host="127.0.0.1", port=server.getsockname()[1])
        assert MosquittoDriver().health(spec, 0.3) is False


def test_installed_mosquitto_is_found_and_runs() -> None:
    """The binary `make setup` installed is what the finder returns, and it is Mosquitto."""
    binary = parts.mosquitto_binary()
    assert binary.is_file() and os.access(binary, os.X_OK)
    out = subprocess.run([str(binary), "-h"], capture_output=True, text=True, timeout=10)
    assert "mosquitto version" in (out.stdout + out.stderr)


def _executable(path: Path) -> Path:
    path.write_text("#!/bin/sh\n", encoding="utf-8")
    path.chmod(0o755)
    return path


def test_mosquitto_found_in_sbin_when_not_on_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    sbin = tmp_path / "sbin"
    sbin.mkdir()
    monkeypatch.setattr(parts, "SBIN_DIRS", (tmp_path / "nowhere", sbin))
    with pytest.raises(MosquittoMissingError, match="make setup"):
        parts.mosquitto_binary()
    binary = _executable(sbin / "mosquitto")
    assert parts.mosquitto_binary() == binary


def test_java_from_java_home_when_not_on_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PATH", str(tmp_path / "empty"))
    monkeypatch.delenv("JAVA_HOME", raising=False)
    with pytest.raises(JavaMissingError):
        parts.java_binary()
    (tmp_path / "jdk" / "bin").mkdir(parents=True)
    java = _executable(tmp_path / "jdk" / "bin" / "java")
    monkeypatch.setenv("JAVA_HOME", str(tmp_path / "jdk"))
    assert parts.java_binary() == java


def test_kafka_parts_need_broker_jars_and_find_log4j(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PLANTKG_KAFKA_HOME", str(tmp_path))
    (tmp_path / "libs").mkdir()
    with pytest.raises(KafkaMissingError, match="PLANTKG_KAFKA_HOME"):
        parts.kafka_parts()
    (tmp_path / "libs" / "kafka_2.13-3.9.1.jar").write_bytes(b"")
    (tmp_path / "config").mkdir()
    (tmp_path / "config" / "log4j.properties").write_text("", encoding="utf-8")
    found = parts.kafka_parts()
    assert found.libs == tmp_path / "libs"
    assert found.classpath == str(tmp_path / "libs" / "*")
    assert found.log4j_config == tmp_path / "config" / "log4j.properties"
    assert found.tools_log4j_config is None


def test_mosquitto_is_woken_at_its_listener() -> None:
    """After SIGTERM the agent wakes a Mosquitto (blocked in epoll with its signals masked) by a
    connection to its listener."""
    spec = BrokerSpec(id="m", iri="urn:m", name="m", kind="mosquitto", host="127.0.0.2", port=18830)
    assert isinstance(MosquittoDriver(), Waking) and MosquittoDriver().wake_address(spec) == ("127.0.0.2", 18830)
    assert not isinstance(KafkaDriver(), Waking)  # a JVM acts on SIGTERM at once
