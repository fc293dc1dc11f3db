"""MirrorMaker 2 for Kafka -> Kafka bridges, the pure parts: mm2.properties, the worker's config
(from a BridgeSpec, as the agent makes it, and through worker.json), and the lag measure."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.agent.workers import mirror_config, _config_text
from engine.drivers.kafka.mirror import MirrorConfig, render_login_properties, render_mm2_properties, topic_pattern
from engine.drivers.kafka.mirror_worker import MirrorWorkerConfig, is_mirror_config, lag_of
from engine.errors import ConfigValueError
from engine.model import BridgeDirection, BridgeEnd, BridgeMechanism, BridgeRoute, BridgeSpec

PLANT = ("127.0.0.2:9092", "127.0.0.3:9092", "127.0.0.4:9092")
SPEC = BridgeSpec(
    local=BridgeEnd("site-1", "kafka", "127.0.0.5", 9092, ("127.0.0.5:9092",)),
    remote=BridgeEnd("plant-1", "kafka", "127.0.0.2", 9092, PLANT),
    mechanism=BridgeMechanism.MIRROR,
    routes=(BridgeRoute("plant.kpi", BridgeDirection.IN), BridgeRoute("line-status_x", BridgeDirection.IN)))


def test_properties_mirror_exactly_the_routes_one_way_keeping_names() -> None:
    text = render_mm2_properties(MirrorConfig(PLANT, ("127.0.0.5:9092",), ("plant.kpi", "line-status_x"), 1))
    lines = set(text.splitlines())
    assert {"clusters=source,target", "source.bootstrap.servers=" + ",".join(PLANT),
            "target.bootstrap.servers=127.0.0.5:9092", "source->target.enabled=true",
            "target->source.enabled=false", "source->target.topics=line-status_x,plant[.]kpi",
            "replication.policy.class=org.apache.kafka.connect.mirror.IdentityReplicationPolicy",
            "emit.heartbeats.enabled=false", "source->target.offset-syncs.topic.location=target",
            "sync.topic.configs.enabled=false", "source->target.sync.group.offsets.enabled=true",
            "replication.factor=1", "offset.storage.replication.factor=1"} <= lines
    assert "\\" not in text  # no backslash for .properties to eat
    assert topic_pattern("a.b.c") == "a[.]b[.]c"


@pytest.mark.parametrize("field,kwargs", [
    ("source", {"source": ("127.0.0.2:9092\nsource->target.topics=.*",)}),
    ("target", {"target": ()}),
    ("topics", {"topics": ("bad topic",)}),
    ("topics", {"topics": ("x,y",)}),
    ("replication", {"replication": 0}),
])
def test_values_that_would_break_the_file_are_refused(field: str, kwargs: dict) -> None:  # type: ignore[type-arg]
    values = {"source": PLANT, "target": ("127.0.0.5:9092",), "topics": ("t",), "replication": 1, **kwargs}
    with pytest.raises(ConfigValueError) as raised:
        MirrorConfig(**values)
    assert raised.value.field == field


def test_the_agent_mirrors_into_the_target_it_carries(tmp_path: Path) -> None:
    cfg = mirror_config(SPEC, tmp_path)
    assert cfg.mirror == MirrorConfig(PLANT, ("127.0.0.5:9092",), ("plant.kpi", "line-status_x"), 1)
    text = _config_text(SPEC, tmp_path, None)
    assert is_mirror_config(text) and MirrorWorkerConfig.from_json(text) == cfg
    three = BridgeSpec(local=BridgeEnd("a-1", "kafka", "127.0.0.2", 9092, PLANT + ("127.0.0.6:9092",)),
                       remote=SPEC.local, mechanism=BridgeMechanism.MIRROR, routes=SPEC.routes)
    assert mirror_config(three, tmp_path).mirror.replication == 3  # internal topics: at most 3
    single = BridgeSpec(local=BridgeEnd("k", "kafka", "127.0.0.7", 9093), remote=SPEC.remote,
                        mechanism=BridgeMechanism.MIRROR, routes=SPEC.routes)
    assert mirror_config(single, tmp_path).mirror.target == ("127.0.0.7:9093",)


def test_a_mirror_copies_into_its_carrier_only(tmp_path: Path) -> None:
    out = BridgeSpec(SPEC.local, SPEC.remote, SPEC.mechanism, (BridgeRoute("plant.kpi", BridgeDirection.OUT),))
    with pytest.raises(ConfigValueError, match="direction in"):
        _config_text(out, tmp_path, None)
    with pytest.raises(ConfigValueError, match="remote token"):
        _config_text(SPEC, tmp_path, "secret")


def test_worker_json_is_checked() -> None:
    assert not is_mirror_config('{"mechanism": "mqtt-kafka"}') and not is_mirror_config("not json")
    with pytest.raises(ConfigValueError):
        MirrorWorkerConfig.from_json('{"mechanism": "kafka-mirror", "bridge_id": "a--b"}')
    good = MirrorWorkerConfig("a--b", MirrorConfig(PLANT, PLANT, ("t",)), Path("/tmp/x"))
    with pytest.raises(ConfigValueError, match="interval"):
        MirrorWorkerConfig.from_json(good.to_json().replace('"interval": 2.0', '"interval": 0'))


def test_lag_counts_what_the_target_lacks_per_partition() -> None:
    source = {("t", 0): 100, ("t", 1): 50, ("u", 0): 7}
    assert lag_of(source, {("t", 0): 100, ("t", 1): 50, ("u", 0): 7}) == 0
    assert lag_of(source, {("t", 0): 90, ("t", 1): 50}) == 10 + 7
    # a target ahead on one partition (another writer) hides nothing on the others
    assert lag_of(source, {("t", 0): 120, ("t", 1): 40, ("u", 0): 7}) == 10


@pytest.mark.parametrize(("name", "internal"), [
    ("__consumer_offsets", True), ("mm2-offsets.source.internal", True), ("source.checkpoints.internal", True),
    ("heartbeats", True), ("source.heartbeats", True), ("plant.kpi", False), ("heartbeats-of-line-1", False)])
def test_mirrormakers_own_topics_are_not_plant_topics(name: str, internal: bool) -> None:
    from engine.drivers.kafka.topics import is_internal
    assert is_internal(name) is internal


PASSWORD = "ab" * 32  # the shape of plantkg's Kafka password (engine.security.kafka_client)


@pytest.mark.parametrize(("source_closed", "target_closed"), [(True, True), (True, False), (False, True)])
def test_a_closed_end_logs_in_as_plantkg_and_an_open_one_does_not(source_closed: bool, target_closed: bool) -> None:
    cfg = MirrorConfig(PLANT, ("127.0.0.5:9092",), ("plant.kpi",), 1, source_closed, target_closed)
    lines = render_mm2_properties(cfg, Path("/state/bridges/a--b/mm2-login.properties")).splitlines()
    assert {"config.providers=file",
            "config.providers.file.class=org.apache.kafka.common.config.provider.FileConfigProvider"} <= set(lines)
    for cluster, closed in (("source", source_closed), ("target", target_closed)):
        login = {f"{cluster}.security.protocol=SASL_PLAINTEXT", f"{cluster}.sasl.mechanism=PLAIN",
                 f"{cluster}.sasl.jaas.config=${{file:/state/bridges/a--b/mm2-login.properties:jaas}}"}
        assert (login <= set(lines)) is closed
        assert any(line.startswith(f"{cluster}.sasl") for line in lines) is closed


def test_the_login_file_holds_the_password_the_properties_do_not() -> None:
    assert render_login_properties(PASSWORD).splitlines()[1] == (
        "jaas=org.apache.kafka.common.security.plain.PlainLoginModule required "
        f'username="plantkg" password="{PASSWORD}";')
    text = render_mm2_properties(MirrorConfig(PLANT, PLANT, ("t",), 1, True, True), Path("/s/mm2-login.properties"))
    assert PASSWORD not in text and "password" not in text


def test_a_closed_mirror_needs_a_login_that_cannot_break_the_files() -> None:
    cfg = MirrorConfig(PLANT, PLANT, ("t",), 1, source_closed=True)
    with pytest.raises(ConfigValueError, match="needs plantkg's login file"):
        render_mm2_properties(cfg)
    with pytest.raises(ConfigValueError) as raised:
        render_login_properties('x"; user_admin="x')
    assert raised.value.field == "password" and "user_admin" not in str(raised.value)
    with pytest.raises(ConfigValueError) as raised:  # the ${file:path:key} syntax would misread it
        render_mm2_properties(cfg, Path("/s/a:b/mm2-login.properties"))
    assert raised.value.field == "login_file"
    with pytest.raises(ConfigValueError, match="true or false"):
        MirrorConfig(PLANT, PLANT, ("t",), 1, source_closed="yes")  # type: ignore[arg-type]
    open_both = render_mm2_properties(MirrorConfig(PLANT, PLANT, ("t",)), Path("/s/mm2-login.properties"))
    assert "sasl" not in open_both and "config.providers" not in open_both  # open: no login at all


def test_the_agent_gives_a_closed_mirror_a_password_file_and_no_password(tmp_path: Path) -> None:
    closed_source = BridgeSpec(SPEC.local, BridgeEnd(**{**SPEC.remote.__dict__, "closed": True}),
                               SPEC.mechanism, SPEC.routes)
    cfg = mirror_config(closed_source, tmp_path)
    assert (cfg.mirror.source_closed, cfg.mirror.target_closed) == (True, False)
    assert cfg.password_file == tmp_path / "remote.token"
    text = _config_text(closed_source, tmp_path, None)
    assert MirrorWorkerConfig.from_json(text) == cfg and "password\"" not in text
    assert mirror_config(SPEC, tmp_path).password_file is None  # both open: no password at all
    with pytest.raises(ConfigValueError, match="cannot be read"):
        cfg.password()
    (tmp_path / "remote.token").write_text(PASSWORD + "\n", encoding="utf-8")
    assert cfg.password() == PASSWORD


def test_a_closed_tls_end_logs_in_over_sasl_ssl() -> None:
    cfg = MirrorConfig(PLANT, ("127.0.0.5:9092",), ("t",), 1, True, False, True, True)
    lines = render_mm2_properties(cfg, Path("/s/mm2-login.properties"), Path("/ca/ca.pem")).splitlines()
    assert {"source.security.protocol=SASL_SSL", "source.sasl.mechanism=PLAIN",
            "source.ssl.truststore.location=/ca/ca.pem", "target.security.protocol=SSL",
            "target.ssl.truststore.location=/ca/ca.pem"} <= set(lines)
    assert not any(line.startswith("target.sasl") for line in lines)
    with pytest.raises(ConfigValueError) as raised:
        render_mm2_properties(cfg, Path("/s/mm2-login.properties"), Path("ca.pem"))  # not absolute
    assert raised.value.field == "ca_file"


def test_an_open_plain_mirrors_worker_json_reads_as_before(tmp_path: Path) -> None:
    """Its config hash is unchanged, so an agent that upgrades does not restart its MirrorMaker."""
    text = _config_text(SPEC, tmp_path, None)
    assert not any(flag in text for flag in ("_closed", "_tls", "password_file", "ca_file"))
