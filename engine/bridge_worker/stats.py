"""The worker's health and counters, as a file its agent reads (``<state_dir>/stats.json``).

The worker rewrites the file atomically (write a temporary file, rename it over the old one) every
``stats_interval`` seconds and whenever a connection comes up or goes down, so a reader never sees
half a file. The agent turns it into the bridge's observed state: RUNNING when ``ready``, CONNECTING
while the worker is alive but not ready; ``updated_at`` tells a stale file (a hung worker) apart.
"""

from __future__ import annotations

import json
from dataclasses import MISSING, asdict, dataclass, fields
from pathlib import Path
from engine.whole_file import write_whole

STATS_FILE = "stats.json"


@dataclass(frozen=True)
class WorkerStats:
    """One snapshot. ``kafka_connected`` is None before the first probe of the Kafka cluster.
    The fields with defaults are the MQTT <-> NGSI worker's (``mechanism`` "mqtt-ngsi"): messages
    upserted, ``refused`` by the context broker (acknowledged, not retried), notifications
    ``skipped`` (the loop rule), and whether the context broker answers. ``forwarded_per_s``:
    messages forwarded per second over the last ~10 s (:mod:`engine.bridge_worker.rate`; 0.0 in
    a file written before the field existed). A MirrorMaker 2's watcher
    (engine.drivers.kafka.mirror_worker) writes the last two fields."""

    bridge_id: str
    pid: int
    ready: bool
    mqtt_connected: bool
    kafka_connected: bool | None
    forwarded_mqtt_to_kafka: int
    forwarded_kafka_to_mqtt: int
    retried: int
    last_error: str | None
    updated_at: float
    mechanism: str = "mqtt-kafka"
    ngsi_connected: bool | None = None
    forwarded_mqtt_to_ngsi: int = 0
    refused: int = 0
    skipped: int = 0
    forwarded_per_s: float = 0.0
    forwarded_kafka_to_kafka: int = 0   # a MirrorMaker 2 (mechanism "kafka-mirror")
    lag: int | None = None              # kafka-mirror: records the source has, the target not yet

    @property
    def forwarded(self) -> int:
        return (self.forwarded_mqtt_to_kafka + self.forwarded_kafka_to_mqtt + self.forwarded_mqtt_to_ngsi
                + self.forwarded_kafka_to_kafka)


def write_stats(state_dir: Path, stats: WorkerStats) -> None:
    """Replace ``state_dir/stats.json`` atomically."""
    write_whole(state_dir / STATS_FILE, json.dumps(asdict(stats)))


def read_stats(state_dir: Path) -> WorkerStats | None:
    """The last snapshot, or None if there is none yet or it cannot be read as one."""
    try:
        data = json.loads((state_dir / STATS_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    names = {f.name for f in fields(WorkerStats)}
    required = {f.name for f in fields(WorkerStats) if f.default is MISSING}
    if not isinstance(data, dict) or not required <= set(data) <= names:
        return None
    return WorkerStats(**data)
