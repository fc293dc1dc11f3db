"""Kafka (KRaft, one node that is both broker and controller): config, storage, command line.

Reused by the Kafka driver. Verified against Kafka 3.9.1 from Maven Central (see
third_party/kafka/pom.xml):

- :func:`render_server_properties` is a pure function of a validated :class:`KafkaNodeConfig`.
- KRaft storage must be formatted once with a cluster id (base64url of 16 random bytes, 22
  characters). The id is kept in ``<broker dir>/cluster.id`` so a restart reuses the formatted data
  directory; formatting is skipped when ``meta.properties`` already carries that id.
- :func:`broker_command` runs ``kafka.Kafka`` straight on the JVM (what kafka-server-start.sh does),
  with a bounded heap and the log4j config that setup wrote (INFO to stdout -> the broker's log).
"""

from __future__ import annotations

import base64
import os
import re
import subprocess
from dataclasses import dataclass
from pathlib import Path

from engine.errors import ConfigValueError, EngineError, ProcessError
from engine.parts import KafkaParts
from engine.values import check_host, check_path, check_port, host_in_url

CLUSTER_ID_FILE = "cluster.id"
DEFAULT_HEAP = "512m"
_CLUSTER_ID = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_-]{21}")  # no leading "-": read as an option
_HEAP = re.compile(r"[1-9][0-9]{0,5}[mMgG]")


@dataclass(frozen=True)
class KafkaNodeConfig:
    """One single-node KRaft cluster. ``advertised_host`` defaults to ``host`` and must be set
    when ``host`` is a wildcard (0.0.0.0, ::), which clients cannot connect to."""

    host: str
    port: int
    controller_port: int
    data_dir: Path
    node_id: int = 1
    advertised_host: str | None = None

    def __post_init__(self) -> None:
        host = check_host("host", self.host)
        object.__setattr__(self, "host", host)
        check_port("port", self.port)
        check_port("controller_port", self.controller_port)
        if self.port == self.controller_port:
            raise ConfigValueError("controller_port", self.controller_port, "must differ from port")
        # log.dirs is a comma-separated list: a comma would split our one directory in two.
        object.__setattr__(self, "data_dir", check_path("data_dir", self.data_dir, forbid=","))
        if isinstance(self.node_id, bool) or not isinstance(self.node_id, int) or self.node_id < 0:
            raise ConfigValueError("node_id", self.node_id, "must be an integer >= 0")
        advertised = check_host("advertised_host", self.advertised_host or host)
        if advertised in ("0.0.0.0", "::"):
            raise ConfigValueError(
                "advertised_host", advertised, "clients cannot connect to a wildcard address"
            )
        object.__setattr__(self, "advertised_host", advertised)

    @property
    def bootstrap_servers(self) -> str:
        """The ``bootstrap.servers`` value clients use."""
        return f"{host_in_url(str(self.advertised_host))}:{self.port}"


def render_server_properties(cfg: KafkaNodeConfig) -> str:
    """The ``server.properties`` text for ``cfg`` (a pure function)."""
    host, adv = host_in_url(cfg.host), host_in_url(str(cfg.advertised_host))
    lines = [
        "# Rendered by plantkg; edits are overwritten.",
        "process.roles=broker,controller",
        f"node.id={cfg.node_id}",
        f"controller.quorum.voters={cfg.node_id}@{adv}:{cfg.controller_port}",
        f"listeners=PLAINTEXT://{host}:{cfg.port},CONTROLLER://{host}:{cfg.controller_port}",
        # Never advertise the controller listener (Kafka refuses it).
        f"advertised.listeners=PLAINTEXT://{adv}:{cfg.port}",
        "listener.security.protocol.map=CONTROLLER:PLAINTEXT,PLAINTEXT:PLAINTEXT",
        "controller.listener.names=CONTROLLER",
        "inter.broker.listener.name=PLAINTEXT",
        f"log.dirs={cfg.data_dir}",
        # One node: every internal topic has a single replica.
        "offsets.topic.replication.factor=1",
        "offsets.topic.num.partitions=1",
        "transaction.state.log.replication.factor=1",
        "transaction.state.log.min.isr=1",
        "group.initial.rebalance.delay.ms=0",
        # Closed by default (issue 13): only the plant creates topics (AdminClient, through the
        # driver). A produce or a metadata request for an unknown topic gets
        # UNKNOWN_TOPIC_OR_PART instead of creating a topic plantkg never declared.
        "auto.create.topics.enable=false",
    ]
    return "\n".join(lines) + "\n"


def new_cluster_id() -> str:
    """A fresh KRaft cluster id: base64url of 16 random bytes, without padding (22 chars).

    Never starting with ``-``: StorageTool would read ``-t -abc...`` as an option (Kafka's own
    ``Uuid.randomUuid`` redraws such ids for the same reason).
    """
    while True:
        cid = base64.urlsafe_b64encode(os.urandom(16)).decode("ascii").rstrip("=")
        if not cid.startswith("-"):
            return cid


def cluster_id(broker_dir: Path) -> str:
    """The cluster id kept in ``broker_dir/cluster.id``, created on first use."""
    path = broker_dir / CLUSTER_ID_FILE
    if path.exists():
        text = path.read_text(encoding="ascii").strip()
        if not _CLUSTER_ID.fullmatch(text):
            raise EngineError(
                f"{path}: {text!r} is not a KRaft cluster id",
                hint="delete the broker directory to start over with a new cluster",
            )
        return text
    broker_dir.mkdir(parents=True, exist_ok=True)
    text = new_cluster_id()
    path.write_text(text + "\n", encoding="ascii")
    return text


def _java_opts(kafka: KafkaParts, heap: str, log4j: Path | None, logs_dir: Path | None) -> list[str]:
    if not _HEAP.fullmatch(heap):
        raise ConfigValueError("heap", heap, "expected a JVM size such as 512m or 1g")
    opts = [f"-Xmx{heap}", "-Djava.awt.headless=true"]
    if logs_dir is not None:
        opts.append(f"-Dkafka.logs.dir={check_path('logs_dir', logs_dir)}")
    if log4j is not None:
        opts.append(f"-Dlog4j.configuration={log4j.as_uri()}")
    return [*opts, "-cp", kafka.classpath]


def storage_format_command(
    kafka: KafkaParts, java: Path, properties_file: Path, cluster: str
) -> list[str]:
    """argv of ``kafka-storage.sh format -t <id> -c <properties>``."""
    if not _CLUSTER_ID.fullmatch(cluster):
        raise ConfigValueError("cluster_id", cluster, "expected 22 base64url characters")
    opts = _java_opts(kafka, "256m", kafka.tools_log4j_config, None)
    return [str(java), *opts, "kafka.tools.StorageTool", "format",
            "-t", cluster, "-c", str(check_path("properties_file", properties_file))]


def _formatted_cluster_id(data_dir: Path) -> str | None:
    meta = data_dir / "meta.properties"
    if not meta.is_file():
        return None
    for line in meta.read_text(encoding="utf-8").splitlines():
        if line.startswith("cluster.id="):
            return line.partition("=")[2].strip()
    return None


def format_storage(
    cfg: KafkaNodeConfig,
    properties_file: Path,
    broker_dir: Path,
    *,
    kafka: KafkaParts,
    java: Path,
    timeout: float = 60.0,
) -> str:
    """Format ``cfg.data_dir`` once for the broker dir's cluster id; return that id.

    Already formatted with the same id: nothing runs. Formatted with another id: refused (Kafka
    would refuse to start on it)."""
    cluster = cluster_id(broker_dir)
    existing = _formatted_cluster_id(cfg.data_dir)
    if existing == cluster:
        return cluster
    if existing is not None:
        raise EngineError(
            f"{cfg.data_dir} is formatted for cluster {existing}, not {cluster}",
            hint=f"delete {cfg.data_dir} (its data is lost) or restore {broker_dir / CLUSTER_ID_FILE}",
        )
    argv = storage_format_command(kafka, java, properties_file, cluster)
    try:
        done = subprocess.run(  # noqa: S603 - argv list, no shell
            argv, capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL
        )
    except subprocess.TimeoutExpired as exc:
        raise ProcessError(f"Kafka storage format took over {timeout:.0f} s") from exc
    if done.returncode != 0:
        raise ProcessError(
            f"Kafka storage format failed (exit {done.returncode}):\n{done.stdout}{done.stderr}"
        )
    return cluster


def broker_command(
    kafka: KafkaParts,
    java: Path,
    properties_file: Path,
    logs_dir: Path,
    heap: str = DEFAULT_HEAP,
) -> list[str]:
    """argv that runs the broker in the foreground (``kafka-server-start.sh`` without the script)."""
    opts = _java_opts(kafka, heap, kafka.log4j_config, logs_dir)
    return [str(java), *opts, "kafka.Kafka", str(check_path("properties_file", properties_file))]
