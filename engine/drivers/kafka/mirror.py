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
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from engine.drivers.kafka import runtime as kafka_runtime
from engine.errors import ConfigValueError
from engine.parts import KafkaParts
from engine.values import check_path

MAIN_CLASS = "org.apache.kafka.connect.mirror.MirrorMaker"
SOURCE, TARGET = "source", "target"
IDENTITY_POLICY = "org.apache.kafka.connect.mirror.IdentityReplicationPolicy"
DEFAULT_HEAP = "256m"
_ADDRESS = re.compile(r"(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.-]+):[0-9]{1,5}")
_TOPIC = re.compile(r"[A-Za-z0-9._-]{1,249}")


@dataclass(frozen=True)
class MirrorConfig:
    """One one-way mirror: the clusters' bootstrap lists, the topics, the target's replication
    factor for MirrorMaker's own topics."""

    source: tuple[str, ...]
    target: tuple[str, ...]
    topics: tuple[str, ...]
    replication: int = 1

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


def topic_pattern(name: str) -> str:
    """A regex matching exactly ``name``: a Kafka name's only regex character is the dot."""
    return name.replace(".", "[.]")


def render_mm2_properties(cfg: MirrorConfig) -> str:
    """The ``mm2.properties`` text (pure)."""
    flow = f"{SOURCE}->{TARGET}"
    rf = cfg.replication
    lines = [
        "# Rendered by plantkg; edits are overwritten.",
        f"clusters={SOURCE},{TARGET}",
        f"{SOURCE}.bootstrap.servers={','.join(cfg.source)}",
        f"{TARGET}.bootstrap.servers={','.join(cfg.target)}",
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
