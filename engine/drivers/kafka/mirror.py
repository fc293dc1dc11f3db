"""MirrorMaker 2 for a Kafka -> Kafka bridge: its configuration (pure) and its command line.

A bridge between two Kafka brokers or clusters (mechanism ``kafka-mirror``, engine.derived.bridge_pairs)
runs one dedicated MirrorMaker 2 (``org.apache.kafka.connect.mirror.MirrorMaker``, the
``connect-mirror`` jars ``make setup`` resolves beside the broker's) on the agent of the target's
lead node; :mod:`engine.drivers.kafka.mirror_worker` supervises it and reports its lag.

Choices (docs/kafka.md "MirrorMaker 2"):

- **Topic names kept**: ``IdentityReplicationPolicy``. The plant names one topic individual on
  both clusters and its subscribers read it under that name; the default policy would write
  ``source.topic`` on the target, a topic the plant never declared. The price: no cycle detection,
  so a mirror runs one way only (engine.derived.bridge_pairs refuses both ways).
- **Only the bridge's topics**: ``source->target.topics`` lists them (``[.]`` for a dot, no
  backslash to survive .properties escaping); the plant (plantkg) creates them on the target
  first, with the plant's settings; ``sync.topic.configs.enabled`` is off so MirrorMaker does not
  overwrite them, and ACL sync is off.
- **Nothing written to the source**: the offset-syncs topic lives on the target
  (``offset-syncs.topic.location=target``); heartbeats are off (they would create a ``heartbeats``
  topic on both clusters and start the reverse flow); MirrorMaker's own topics all end in
  ``.internal``, which plantkg's Kafka driver does not report as plant topics.
- **Offset translation**: checkpoints are emitted every 5 s into ``source.checkpoints.internal``
  on the target and the committed offsets of consumer groups idle on the target are synced
  (``sync.group.offsets.enabled``), so a consumer group can move to the target cluster.
- **Refresh** of topics and groups every 5 s (the default is 10 min), one task.
- **Closed ends** (docs/security.md, "MirrorMaker 2 at a closed Kafka"): at a Kafka closed to
  anonymous clients, every client MirrorMaker 2 opens there (its consumer, producer and admin
  clients, and its Connect worker's on the target) logs in as plantkg's own Kafka principal with
  SASL/PLAIN, per end (``<cluster>.sasl.jaas.config``); an open end gets no login. The login is a
  reference, ``${file:<login file>:jaas}``, resolved by Kafka's ``FileConfigProvider`` when a
  client starts: MirrorMaker 2 stores its connectors' configuration in a topic on the target
  (``mm2-configs.source.internal``), and a literal password would be written there, into the
  target's log segments (files others may read) and to any client allowed to read that topic.
  Only the login file (:func:`render_login_properties`, written 0600) holds the password.
- **TLS ends** (``pk:tls true``, docs/security.md, "TLS (Kafka)"): every client of such an end
  speaks TLS (SSL, or SASL_SSL where it is closed too) and trusts the plant CA only (a PEM
  truststore, the agent's copy of the CA certificate), the broker's address checked against its
  certificate, as the driver's AdminClient does.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from engine.drivers.kafka import runtime as kafka_runtime
from engine.errors import ConfigValueError
from engine.parts import KafkaParts
from engine.security import kafka_client
from engine.values import check_path

#: plantkg's password, as engine.security.kafka_client derives it (a JAAS-safe value).
_PASSWORD = re.compile(r"[0-9a-f]{32,128}")

MAIN_CLASS = "org.apache.kafka.connect.mirror.MirrorMaker"
#: The name MirrorMaker 2's configuration gives Kafka's FileConfigProvider.
FILE_PROVIDER = "file"
SOURCE, TARGET = "source", "target"
IDENTITY_POLICY = "org.apache.kafka.connect.mirror.IdentityReplicationPolicy"
DEFAULT_HEAP = "256m"
_ADDRESS = re.compile(r"(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.-]+):[0-9]{1,5}")
_TOPIC = re.compile(r"[A-Za-z0-9._-]{1,249}")


@dataclass(frozen=True)
class MirrorConfig:
    """One one-way mirror: the clusters' bootstrap lists, the topics, the target's replication
    factor for MirrorMaker's own topics, which end is closed (plantkg logs in there) and which
    speaks TLS."""

    source: tuple[str, ...]
    target: tuple[str, ...]
    topics: tuple[str, ...]
    replication: int = 1
    source_closed: bool = False
    target_closed: bool = False
    source_tls: bool = False
    target_tls: bool = False

    def __post_init__(self) -> None:
        for name in ("source", "target"):
            addresses = getattr(self, name)
            if not addresses or any(not isinstance(a, str) or not _ADDRESS.fullmatch(a) for a in addresses):
                raise ConfigValueError(name, addresses, "expected a non-empty list of host:port")
        if not self.topics or any(not isinstance(t, str) or not _TOPIC.fullmatch(t) for t in self.topics):
            raise ConfigValueError("topics", self.topics, "expected Kafka topic names (A-Z a-z 0-9 . _ -)")
        if isinstance(self.replication, bool) or not isinstance(self.replication, int) \
                or not 1 <= self.replication <= 32_767:
            raise ConfigValueError("replication", self.replication, "must be an integer in 1..32767")
        for name in ("source_closed", "target_closed", "source_tls", "target_tls"):
            if not isinstance(getattr(self, name), bool):
                raise ConfigValueError(name, getattr(self, name), "must be true or false")

    @property
    def closed(self) -> bool:
        """Some end authenticates every client: the mirror needs plantkg's password."""
        return self.source_closed or self.target_closed

    @property
    def tls(self) -> bool:
        """Some end speaks TLS: the mirror needs the plant CA's certificate."""
        return self.source_tls or self.target_tls


def topic_pattern(name: str) -> str:
    """A regex matching exactly ``name``: a Kafka name's only regex character is the dot."""
    return name.replace(".", "[.]")


def render_login_properties(password: str) -> str:
    """The login file's text (pure): the JAAS line that logs a client in as plantkg."""
    if not isinstance(password, str) or not _PASSWORD.fullmatch(password):
        raise ConfigValueError("password", "(not shown)",
                               "expected 32 to 128 hex digits (engine.security.kafka_client.password)")
    return ("# Rendered by plantkg (mode 0600): plantkg's Kafka login, read by MirrorMaker 2's clients.\n"
            "jaas=org.apache.kafka.common.security.plain.PlainLoginModule required "
            f'username="{kafka_client.USER}" password="{password}";\n')


def end_lines(cluster: str, closed: bool, tls: bool, login_file: Path | None, ca_file: Path | None) -> list[str]:
    """The lines that make every client of ``cluster`` log in as plantkg (SASL/PLAIN) where it is
    ``closed``, its JAAS line read from ``login_file`` when the client starts (never stored by
    MirrorMaker 2), and speak TLS trusting ``ca_file`` only where it speaks ``tls``."""
    lines = []
    if closed:
        # nothing the ${provider:path:key} syntax reads in the path
        path = check_path("login_file", login_file, forbid=":{}$")
        lines += [f"{cluster}.sasl.mechanism=PLAIN",
                  f"{cluster}.sasl.jaas.config=${{{FILE_PROVIDER}:{path}:jaas}}"]
    if tls:
        lines += [f"{cluster}.ssl.truststore.type=PEM",
                  f"{cluster}.ssl.truststore.location={check_path('ca_file', ca_file)}",
                  f"{cluster}.ssl.endpoint.identification.algorithm=https"]
    if closed or tls:
        protocol = ("SASL_SSL" if tls else "SASL_PLAINTEXT") if closed else "SSL"
        lines.insert(0, f"{cluster}.security.protocol={protocol}")
    return lines


def render_mm2_properties(cfg: MirrorConfig, login_file: Path | None = None, ca_file: Path | None = None) -> str:
    """The ``mm2.properties`` text (pure). ``login_file``: where plantkg's login is
    (:func:`render_login_properties`), needed when an end is closed (the text holds no secret);
    ``ca_file``: the plant CA's certificate, needed when an end speaks TLS."""
    if cfg.closed and login_file is None:
        raise ConfigValueError("login_file", None, "a mirror with a closed end needs plantkg's login file")
    if cfg.tls and ca_file is None:
        raise ConfigValueError("ca_file", None, "a mirror with a TLS end needs the plant CA's certificate")
    ends = [end_lines(SOURCE, cfg.source_closed, cfg.source_tls, login_file, ca_file),
            end_lines(TARGET, cfg.target_closed, cfg.target_tls, login_file, ca_file)]
    logins = [line for lines in ends for line in lines]
    if cfg.closed:
        logins = [f"config.providers={FILE_PROVIDER}",
                  f"config.providers.{FILE_PROVIDER}.class=org.apache.kafka.common.config.provider.FileConfigProvider",
                  *logins]
    flow = f"{SOURCE}->{TARGET}"
    rf = cfg.replication
    lines = [
        "# Rendered by plantkg; edits are overwritten.",
        f"clusters={SOURCE},{TARGET}",
        f"{SOURCE}.bootstrap.servers={','.join(cfg.source)}",
        f"{TARGET}.bootstrap.servers={','.join(cfg.target)}",
        *logins,
        f"{flow}.enabled=true",
        f"{TARGET}->{SOURCE}.enabled=false",
        f"{flow}.topics={','.join(topic_pattern(t) for t in sorted(cfg.topics))}",
        f"replication.policy.class={IDENTITY_POLICY}",
        "emit.heartbeats.enabled=false",
        f"{flow}.emit.checkpoints.enabled=true",
        f"{flow}.emit.checkpoints.interval.seconds=5",
        f"{flow}.sync.group.offsets.enabled=true",
        f"{flow}.sync.group.offsets.interval.seconds=5",
        f"{flow}.offset-syncs.topic.location=target",
        "sync.topic.configs.enabled=false",
        "sync.topic.acls.enabled=false",
        "refresh.topics.interval.seconds=5",
        "refresh.groups.interval.seconds=5",
        "tasks.max=1",
        f"replication.factor={rf}",
        f"checkpoints.topic.replication.factor={rf}",
        f"heartbeats.topic.replication.factor={rf}",
        f"offset-syncs.topic.replication.factor={rf}",
        f"offset.storage.replication.factor={rf}",
        f"status.storage.replication.factor={rf}",
        f"config.storage.replication.factor={rf}",
        # acks=all and idempotence are the producer defaults since Kafka 3.0: a copied record is
        # acknowledged by the target's in-sync replicas before its source offset is committed.
    ]
    return "\n".join(lines) + "\n"


def mirror_command(kafka: KafkaParts, java: Path, properties_file: Path, logs_dir: Path,
                   heap: str = DEFAULT_HEAP) -> list[str]:
    """argv that runs MirrorMaker 2 in the foreground (``connect-mirror-maker.sh`` without it)."""
    opts = kafka_runtime.java_options(kafka, heap, kafka.log4j_config, logs_dir)
    return [str(java), *opts, MAIN_CLASS, str(check_path("properties_file", properties_file))]
