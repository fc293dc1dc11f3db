"""Golden tests of the Mosquitto and Kafka renderers and of their refusal of unsafe values."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.drivers.kafka import runtime as kafka_runtime
from engine.drivers.mosquitto import runtime as mosquitto_runtime
from engine.errors import ConfigValueError, EngineError
from engine.drivers.kafka.runtime import KafkaNodeConfig, render_server_properties
from engine.drivers.mosquitto.runtime import DEFAULT_SAVE_SECONDS, MosquittoConfig, render_mosquitto_conf
from engine.parts import KafkaParts

MOSQUITTO_GOLDEN = """\
# Rendered by plantkg; edits are overwritten.
per_listener_settings false
listener 18830 127.0.0.2
allow_anonymous true
max_queued_messages 1000000
max_inflight_messages 1000
set_tcp_nodelay true
persistence false
log_dest file /var/lib/plantkg/m1/mosquitto.log
log_type error
log_type warning
log_type notice
log_type information
log_timestamp true
connection_messages true
"""

KAFKA_GOLDEN = """\
# Rendered by plantkg; edits are overwritten.
process.roles=broker,controller
node.id=1
controller.quorum.voters=1@127.0.0.3:19093
listeners=PLAINTEXT://127.0.0.3:19092,CONTROLLER://127.0.0.3:19093
advertised.listeners=PLAINTEXT://127.0.0.3:19092
listener.security.protocol.map=CONTROLLER:PLAINTEXT,PLAINTEXT:PLAINTEXT
controller.listener.names=CONTROLLER
inter.broker.listener.name=PLAINTEXT
log.dirs=/var/lib/plantkg/k1/data
offsets.topic.replication.factor=1
offsets.topic.num.partitions=1
transaction.state.log.replication.factor=1
transaction.state.log.min.isr=1
group.initial.rebalance.delay.ms=0
auto.create.topics.enable=false
"""


def mosquitto(**overrides) -> MosquittoConfig:
    values = dict(host="127.0.0.2", port=18830, log_file=Path("/var/lib/plantkg/m1/mosquitto.log"))
    return MosquittoConfig(**{**values, **overrides})


def kafka(**overrides) -> KafkaNodeConfig:
    values = dict(host="127.0.0.3", port=19092, controller_port=19093,
                  data_dir=Path("/var/lib/plantkg/k1/data"))
    return KafkaNodeConfig(**{**values, **overrides})


# --- Mosquitto -----------------------------------------------------------------------------------

def test_mosquitto_conf_golden() -> None:
    assert render_mosquitto_conf(mosquitto()) == MOSQUITTO_GOLDEN


def test_mosquitto_conf_run_as_and_ipv6() -> None:
    text = render_mosquitto_conf(mosquitto(host="::1", run_as="plantkg"))
    assert "listener 18830 ::1\n" in text
    assert text.endswith("user plantkg\n")


def test_mosquitto_conf_is_pure() -> None:
    assert render_mosquitto_conf(mosquitto()) == render_mosquitto_conf(mosquitto())


def test_mosquitto_command(tmp_path: Path) -> None:
    conf = tmp_path / "mosquitto.conf"
    argv = mosquitto_runtime.mosquitto_command(Path("/usr/sbin/mosquitto"), conf)
    assert argv == ["/usr/sbin/mosquitto", "-c", str(conf)]


BAD_COMMON = [
    ("port", 0), ("port", 65536), ("port", -1), ("port", "1883"), ("port", True), ("port", 1883.0),
    ("host", "localhost"), ("host", "127.0.0.1\nlistener 1 0.0.0.0"), ("host", "256.0.0.1"),
    ("host", ""), ("host", None), ("host", "127.0.0.1 "),
]


@pytest.mark.parametrize(("field", "value"), [
    *BAD_COMMON,
    ("log_file", "relative/mosquitto.log"),
    ("log_file", "/tmp/x.log\nlistener 1 0.0.0.0"),
    ("log_file", "/tmp/x.log\r"),
    ("log_file", "/tmp/a\\b.log"),
    ("log_file", "/tmp/a\tb.log"),
    ("log_file", "/tmp/x.log "),
    ("log_file", 42),
    ("run_as", "root\nlistener 1 0.0.0.0"),
    ("run_as", ""),
    ("run_as", "Bad User"),
])
def test_mosquitto_refuses(field: str, value: object) -> None:
    with pytest.raises(ConfigValueError) as err:
        mosquitto(**{field: value})
    assert err.value.field == field
    assert isinstance(err.value, ValueError)  # also a ValueError for generic callers


# --- Kafka ---------------------------------------------------------------------------------------

def test_server_properties_golden() -> None:
    assert render_server_properties(kafka()) == KAFKA_GOLDEN


def test_server_properties_ipv6_and_advertised() -> None:
    text = render_server_properties(kafka(host="::", advertised_host="::1"))
    assert "listeners=PLAINTEXT://[::]:19092,CONTROLLER://[::]:19093\n" in text
    assert "advertised.listeners=PLAINTEXT://[::1]:19092\n" in text
    assert "controller.quorum.voters=1@[::1]:19093\n" in text
    assert kafka(host="::", advertised_host="::1").bootstrap_servers == "[::1]:19092"


def test_controller_never_advertised() -> None:
    adv = [l for l in render_server_properties(kafka()).splitlines() if l.startswith("advertised")]
    assert adv == ["advertised.listeners=PLAINTEXT://127.0.0.3:19092"]


@pytest.mark.parametrize(("field", "value"), [
    *BAD_COMMON,
    ("controller_port", 0), ("controller_port", "9093"),
    ("controller_port", 19092),  # same as port
    ("data_dir", "data"), ("data_dir", "/tmp/a,/tmp/b"), ("data_dir", "/tmp/d\nnode.id=2"),
    ("data_dir", "/tmp/a\\b"),
    ("node_id", -1), ("node_id", "1"), ("node_id", False),
    ("advertised_host", "kafka.example"),
])
def test_kafka_refuses(field: str, value: object) -> None:
    with pytest.raises(ConfigValueError) as err:
        kafka(**{field: value})
    assert err.value.field == field


def test_kafka_refuses_wildcard_advertised() -> None:
    with pytest.raises(ConfigValueError) as err:
        kafka(host="0.0.0.0")
    assert err.value.field == "advertised_host"


def test_cluster_id_is_base64url_of_16_bytes() -> None:
    import base64

    ids = {kafka_runtime.new_cluster_id() for _ in range(50)}
    assert len(ids) == 50
    for cid in ids:
        assert len(cid) == 22
        assert len(base64.urlsafe_b64decode(cid + "==")) == 16


def test_cluster_id_kept_in_broker_dir(tmp_path: Path) -> None:
    first = kafka_runtime.cluster_id(tmp_path / "k1")
    assert kafka_runtime.cluster_id(tmp_path / "k1") == first
    assert (tmp_path / "k1" / "cluster.id").read_text().strip() == first
    (tmp_path / "k1" / "cluster.id").write_text("not-an-id\n")
    with pytest.raises(EngineError):
        kafka_runtime.cluster_id(tmp_path / "k1")


def test_format_storage_refuses_foreign_data_dir(tmp_path: Path) -> None:
    cfg = kafka(data_dir=tmp_path / "data")
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "meta.properties").write_text("version=1\ncluster.id=AAAAAAAAAAAAAAAAAAAAAA\n")
    fake = KafkaParts("3.9.1", tmp_path, tmp_path / "libs", None, None)
    with pytest.raises(EngineError, match="formatted for cluster"):
        kafka_runtime.format_storage(cfg, tmp_path / "server.properties", tmp_path / "b",
                                     kafka=fake, java=Path("/nonexistent/java"))


def test_format_storage_skips_when_already_formatted(tmp_path: Path) -> None:
    cfg = kafka(data_dir=tmp_path / "data")
    cid = kafka_runtime.cluster_id(tmp_path / "b")
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "meta.properties").write_text(f"version=1\ncluster.id={cid}\n")
    fake = KafkaParts("3.9.1", tmp_path, tmp_path / "libs", None, None)
    # java does not exist: returning proves no JVM was started
    assert kafka_runtime.format_storage(cfg, tmp_path / "p", tmp_path / "b",
                                        kafka=fake, java=Path("/nonexistent/java")) == cid


def test_broker_command(tmp_path: Path) -> None:
    log4j = tmp_path / "log4j.properties"
    fake = KafkaParts("3.9.1", tmp_path, tmp_path / "libs", log4j, None)
    argv = kafka_runtime.broker_command(fake, Path("/usr/bin/java"), tmp_path / "server.properties",
                                        logs_dir=tmp_path / "logs")
    assert argv[0] == "/usr/bin/java"
    assert "-Xmx512m" in argv
    assert f"-Dlog4j.configuration={log4j.as_uri()}" in argv
    assert f"-Dkafka.logs.dir={tmp_path / 'logs'}" in argv
    assert argv[argv.index("-cp") + 1] == f"{tmp_path / 'libs'}/*"
    assert argv[-2:] == ["kafka.Kafka", str(tmp_path / "server.properties")]


def test_storage_format_command(tmp_path: Path) -> None:
    fake = KafkaParts("3.9.1", tmp_path, tmp_path / "libs", None, None)
    cid = kafka_runtime.new_cluster_id()
    argv = kafka_runtime.storage_format_command(fake, Path("/usr/bin/java"), tmp_path / "s.p", cid)
    assert argv[-6:] == ["kafka.tools.StorageTool", "format", "-t", cid, "-c", str(tmp_path / "s.p")]
    with pytest.raises(ConfigValueError):
        kafka_runtime.storage_format_command(fake, Path("/usr/bin/java"), tmp_path / "s", "bad id")


@pytest.mark.parametrize("heap", ["512", "1G -XX:+Evil", "", "0m"])
def test_broker_command_refuses_bad_heap(tmp_path: Path, heap: str) -> None:
    fake = KafkaParts("3.9.1", tmp_path, tmp_path / "libs", None, None)
    with pytest.raises(ConfigValueError):
        kafka_runtime.broker_command(fake, Path("/usr/bin/java"), tmp_path / "s", tmp_path, heap=heap)


@pytest.mark.parametrize(("value", "expected"), [
    ("", []),
    ("  ", []),
    ("-XX:TieredStopAtLevel=1 -XX:+UseSerialGC", ["-XX:TieredStopAtLevel=1", "-XX:+UseSerialGC"]),
    ("-XX:-UseCompressedOops", ["-XX:-UseCompressedOops"]),
])
def test_extra_jvm_options_are_xx_flags_from_the_environment(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, value: str, expected: list[str]) -> None:
    assert kafka_runtime.extra_jvm_options({kafka_runtime.JVM_OPTS_ENV: value}) == expected
    monkeypatch.setenv(kafka_runtime.JVM_OPTS_ENV, value)
    fake = KafkaParts("3.9.1", tmp_path, tmp_path / "libs", None, None)
    argv = kafka_runtime.broker_command(fake, Path("/usr/bin/java"), tmp_path / "s.p", logs_dir=tmp_path)
    assert [a for a in argv if a.startswith("-XX:")] == expected
    assert argv.index("-cp") > max((argv.index(o) for o in expected), default=0)


@pytest.mark.parametrize("value", ["-Xmx8g", "-XX:+Evil;rm", "-XX:OnOutOfMemoryError=sh -c x", "-jar x.jar",
                                   "-Dlog4j.configuration=http://x", "-XX:", "--XX:+A", "-XX:+A\n-cp"])
def test_extra_jvm_options_refuse_anything_but_an_xx_flag(value: str) -> None:
    with pytest.raises(ConfigValueError) as caught:
        kafka_runtime.extra_jvm_options({kafka_runtime.JVM_OPTS_ENV: value})
    assert kafka_runtime.JVM_OPTS_ENV in str(caught.value)


def test_the_storage_tool_runs_on_c1_alone(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(kafka_runtime.JVM_OPTS_ENV, raising=False)
    fake = KafkaParts("3.9.1", tmp_path, tmp_path / "libs", None, None)
    argv = kafka_runtime.storage_format_command(fake, Path("/usr/bin/java"), tmp_path / "s.p",
                                                kafka_runtime.new_cluster_id())
    assert "-XX:TieredStopAtLevel=1" in argv[:argv.index("-cp")]
    broker = kafka_runtime.broker_command(fake, Path("/usr/bin/java"), tmp_path / "s.p", logs_dir=tmp_path)
    assert not [a for a in broker if a.startswith("-XX:")]  # a broker keeps C2 unless told


def test_cluster_id_never_starts_with_a_dash() -> None:
    """StorageTool reads ``-t -abc`` as an option; one id in 64 would start with '-' if drawn blindly."""
    ids = [kafka_runtime.new_cluster_id() for _ in range(3000)]
    assert not [i for i in ids if i.startswith("-")]
    with pytest.raises(EngineError, match="cluster_id"):  # refused before any part is looked at
        kafka_runtime.storage_format_command(None, Path("/usr/bin/java"),  # type: ignore[arg-type]
                                             Path("/tmp/x.properties"), "-" + "A" * 21)


def test_mosquitto_saves_after_every_change_when_asked() -> None:
    text = render_mosquitto_conf(mosquitto(data_dir=Path("/var/lib/plantkg/m1/data"), persist_every=1))
    assert "persistence true\npersistence_location /var/lib/plantkg/m1/data/\n" \
        "autosave_on_changes true\nautosave_interval 1\n" in text
    # no pk:persistEvery: saved by time, every DEFAULT_SAVE_SECONDS s: saving by changes made a
    # broker with a backlog do little but save (benchmarks/bench_durability, docs/bridges.md)
    default = render_mosquitto_conf(mosquitto(data_dir=Path("/var/lib/plantkg/m1/data")))
    assert "persistence true\npersistence_location /var/lib/plantkg/m1/data/\n" \
        f"autosave_interval {DEFAULT_SAVE_SECONDS}\n" in default
    assert "autosave_on_changes" not in default


@pytest.mark.parametrize("every", [0, -1, 1_000_001, True, "1"])
def test_mosquitto_refuses_a_bad_save_policy(every: object) -> None:
    with pytest.raises(ConfigValueError, match="persist_every"):
        mosquitto(data_dir=Path("/var/lib/plantkg/m1/data"), persist_every=every)


def test_mosquitto_save_policy_needs_persistence() -> None:
    with pytest.raises(ConfigValueError, match="needs a data_dir"):
        mosquitto(persist_every=1)
