"""Kafka (KRaft): a node's config, its storage format and its command line.

A node is alone (one JVM that is broker and controller, its own quorum) or one of a multi-node
cluster (engine.derived.kafka_cluster), with its roles and the quorum's voters.

Reused by the Kafka driver. Verified against Kafka 3.9.1 from Maven Central (see
third_party/kafka/pom.xml):

- :func:`render_server_properties` is a pure function of a validated :class:`KafkaNodeConfig`.
- KRaft storage must be formatted once with a cluster id (base64url of 16 bytes, 22 characters):
  random for a node alone, derived from the graph for a cluster's nodes (all share it). The id is
  kept in ``<broker dir>/cluster.id`` so a restart reuses the formatted data directory;
  formatting is skipped when ``meta.properties`` already carries that id.
- :func:`broker_command` runs ``kafka.Kafka`` straight on the JVM (what kafka-server-start.sh does),
  with a bounded heap and the log4j config that setup wrote (INFO to stdout -> the broker's log).
"""

from __future__ import annotations

import base64
import os
import re
import subprocess
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from engine.errors import ConfigValueError, EngineError, ProcessError
from engine.parts import KafkaParts
from engine.security import kafka_client
from engine.values import check_host, check_path, check_port, host_in_url

CLUSTER_ID_FILE = "cluster.id"
DEFAULT_HEAP = "512m"
_CLUSTER_ID = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_-]{21}")  # no leading "-": read as an option
_HEAP = re.compile(r"[1-9][0-9]{0,5}[mMgG]")
_PASSWORD = re.compile(r"[0-9a-f]{32,128}")
#: Extra JVM options for every Kafka process plantkg starts (brokers, MirrorMaker, the storage
#: tool), read from the environment of the process that starts them (the agent): HotSpot ``-XX:``
#: flags only, each checked, e.g. ``-XX:TieredStopAtLevel=1 -XX:+UseSerialGC`` where many
#: short-lived brokers share few cores (the test suite). Kafka's own scripts read
#: ``KAFKA_JVM_PERFORMANCE_OPTS`` for the same purpose; plantkg runs the JVM without them.
JVM_OPTS_ENV = "PLANTKG_KAFKA_JVM_OPTS"
_XX_OPTION = re.compile(r"-XX:(?:[+-][A-Za-z][A-Za-z0-9]{0,80}|[A-Za-z][A-Za-z0-9]{0,80}=[A-Za-z0-9._:+-]{1,80})")
#: The storage format tool runs once for a second or two: the C1 compiler alone starts it sooner,
#: and nothing in it lives long enough to gain from C2.
_ONE_SHOT_OPTIONS = ("-XX:TieredStopAtLevel=1",)
#: The principal plantkg's own clients (the driver's AdminClient, the bridge workers, the nodes
#: between themselves) use on a closed Kafka: a super user, authenticated with SASL/PLAIN.
INTERNAL_USER = kafka_client.USER
SCRAM = "SCRAM-SHA-512"
AUTHORIZER = "org.apache.kafka.metadata.authorizer.StandardAuthorizer"


@dataclass(frozen=True)
class KafkaTls:
    """A TLS-only node's files, both PEM (Kafka 3.x reads PEM stores): ``keystore``, the node's
    private key (unencrypted PKCS#8) followed by its certificate; ``truststore``, the plant CA's
    certificate (the node verifies against it the controller listeners it connects to, its own
    or the quorum's, and, in a cluster, the other nodes' broker listeners)."""

    keystore: Path
    truststore: Path

    def __post_init__(self) -> None:
        object.__setattr__(self, "keystore", check_path("tls.keystore", self.keystore))
        object.__setattr__(self, "truststore", check_path("tls.truststore", self.truststore))


@dataclass(frozen=True)
class KafkaNodeConfig:
    """One KRaft node. Alone (``voters`` empty) it is a single-node cluster, broker and controller
    in one JVM, its own quorum. In a cluster it has ``roles`` ("broker", "controller" or both) and
    lists the quorum's ``voters`` as ``(node id, host, controller port)``; a controller-only node
    listens for the quorum on ``port`` (``controller_port`` is then ``port``). ``replication``:
    the internal topics' replication factor; ``min_insync``: the cluster's default
    ``min.insync.replicas`` (None: Kafka's, 1). ``advertised_host`` defaults to ``host`` and must
    be set when ``host`` is a wildcard (0.0.0.0, ::), which clients cannot connect to."""

    host: str
    port: int
    controller_port: int
    data_dir: Path
    node_id: int = 1
    advertised_host: str | None = None
    roles: tuple[str, ...] = ("broker", "controller")
    voters: tuple[tuple[int, str, int], ...] = ()
    replication: int = 1
    min_insync: int | None = None
    internal_password: str | None = None  # closed: SASL on every listener (docs/security.md)
    tls: KafkaTls | None = None           # every listener speaks TLS only (client, inter-broker, quorum)

    def __post_init__(self) -> None:
        host = check_host("host", self.host)
        object.__setattr__(self, "host", host)
        check_port("port", self.port)
        check_port("controller_port", self.controller_port)
        roles = self.roles
        if not roles or len(set(roles)) != len(roles) or not set(roles) <= {"broker", "controller"}:
            raise ConfigValueError("roles", roles, "expected 'broker', 'controller' or both")
        object.__setattr__(self, "roles", tuple(sorted(roles)))
        if self.port == self.controller_port and self.roles != ("controller",):
            raise ConfigValueError("controller_port", self.controller_port, "must differ from port")
        if self.roles == ("controller",) and self.controller_port != self.port:
            raise ConfigValueError("controller_port", self.controller_port,
                                   "a controller-only node listens for the quorum on its port")
        # log.dirs is a comma-separated list: a comma would split our one directory in two.
        object.__setattr__(self, "data_dir", check_path("data_dir", self.data_dir, forbid=","))
        for name in ("node_id", "replication"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < (0 if name == "node_id" else 1):
                raise ConfigValueError(name, value, "must be an integer >= " + ("0" if name == "node_id" else "1"))
        if self.min_insync is not None and (isinstance(self.min_insync, bool)
                                            or not isinstance(self.min_insync, int) or self.min_insync < 1):
            raise ConfigValueError("min_insync", self.min_insync, "must be an integer >= 1")
        voters = []
        for node_id, vhost, vport in self.voters:
            if isinstance(node_id, bool) or not isinstance(node_id, int) or node_id < 0:
                raise ConfigValueError("voters", node_id, "a voter's node id must be an integer >= 0")
            voters.append((node_id, check_host("voters", vhost), check_port("voters", vport)))
        if len({v[0] for v in voters}) != len(voters):
            raise ConfigValueError("voters", self.voters, "two voters share a node id")
        object.__setattr__(self, "voters", tuple(sorted(voters)))
        if self.internal_password is not None and not _PASSWORD.fullmatch(self.internal_password):
            raise ConfigValueError("internal_password", "(not shown)",
                                   "expected 32 to 128 hex digits (engine.security.kafka_client.password)")
        if self.tls is not None and not isinstance(self.tls, KafkaTls):
            raise ConfigValueError("tls", self.tls, "expected a KafkaTls or None")
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
    broker, controller = "broker" in cfg.roles, "controller" in cfg.roles
    voters = cfg.voters or ((cfg.node_id, str(cfg.advertised_host), cfg.controller_port),)
    closed = cfg.internal_password is not None
    client = listener_protocol(closed, cfg.tls is not None)
    listeners = ([f"{client}://{host}:{cfg.port}"] if broker else []) \
        + ([f"CONTROLLER://{host}:{cfg.controller_port}"] if controller else [])
    lines = [
        "# Rendered by plantkg; edits are overwritten.",
        f"process.roles={','.join(cfg.roles)}",
        f"node.id={cfg.node_id}",
        "controller.quorum.voters=" + ",".join(f"{n}@{host_in_url(h)}:{p}" for n, h, p in voters),
        f"listeners={','.join(listeners)}",
    ]
    if broker:  # never advertise the controller listener (Kafka refuses it)
        lines.append(f"advertised.listeners={client}://{adv}:{cfg.port}")
    lines += [
        f"listener.security.protocol.map=CONTROLLER:{client},{client}:{client}",
        "controller.listener.names=CONTROLLER",
    ]
    if broker:
        lines.append(f"inter.broker.listener.name={client}")
    if closed:
        lines += _sasl_lines(str(cfg.internal_password), client)
    if cfg.tls is not None:
        lines += _tls_lines(cfg.tls)
    replication = cfg.replication
    lines += [
        f"log.dirs={cfg.data_dir}",
        # Internal topics: one replica per broker node, at most 3 (Kafka's default); a single node
        # has one.
        f"offsets.topic.replication.factor={replication}",
        "offsets.topic.num.partitions=1",
        f"transaction.state.log.replication.factor={replication}",
        f"transaction.state.log.min.isr={min(2, replication)}",
        "group.initial.rebalance.delay.ms=0",
        # Closed by default (issue 13): only the plant creates topics (AdminClient, through the
        # driver). A produce or a metadata request for an unknown topic gets
        # UNKNOWN_TOPIC_OR_PART instead of creating a topic plantkg never declared.
        "auto.create.topics.enable=false",
    ]
    if cfg.voters:  # a cluster node: a topic that sets no replication factor gets the cluster's
        lines.append(f"default.replication.factor={replication}")
    if cfg.min_insync is not None:
        lines.append(f"min.insync.replicas={cfg.min_insync}")
    return "\n".join(lines) + "\n"


def listener_protocol(closed: bool, tls: bool) -> str:
    """The client listener's security protocol (also its listener name): SASL for a closed node,
    SSL for a TLS one."""
    return ("SASL_SSL" if closed else "SSL") if tls else ("SASL_PLAINTEXT" if closed else "PLAINTEXT")


def _tls_lines(tls: KafkaTls) -> list[str]:
    """A TLS-only node (issue 13): its certificate and key from a PEM keystore, the plant CA as
    its truststore, TLS 1.2 or newer, no client certificates asked, the peer's address checked
    against its certificate. Unprefixed ``ssl.*`` settings apply to every listener of the node
    and to its own client side (Kafka's fallback for a listener without
    ``listener.name.<name>.ssl.*``): the client listener, which is also the inter-broker one,
    and the controller listener, on the server side and when the node connects to the quorum's
    voters and to the other nodes (each at the host its certificate names)."""
    return [
        "ssl.keystore.type=PEM",
        f"ssl.keystore.location={tls.keystore}",
        "ssl.truststore.type=PEM",
        f"ssl.truststore.location={tls.truststore}",
        "ssl.enabled.protocols=TLSv1.2,TLSv1.3",
        "ssl.client.auth=none",
        "ssl.endpoint.identification.algorithm=https",
    ]


def _sasl_lines(password: str, listener: str = "SASL_PLAINTEXT") -> list[str]:
    """A closed Kafka (issue 13): clients authenticate with SCRAM-SHA-512 (the plant's users,
    created through the AdminClient), plantkg's own principal with PLAIN (a static JAAS user, so
    the nodes and the controller listener need no SCRAM credential before the metadata is up);
    KRaft's StandardAuthorizer denies what no ACL allows, and plantkg is its only super user."""
    plain = (f'org.apache.kafka.common.security.plain.PlainLoginModule required username="{INTERNAL_USER}" '
             f'password="{password}" user_{INTERNAL_USER}="{password}";')
    return [
        f"sasl.enabled.mechanisms={SCRAM},PLAIN",
        "sasl.mechanism.inter.broker.protocol=PLAIN",
        "sasl.mechanism.controller.protocol=PLAIN",
        f"listener.name.{listener.lower()}.plain.sasl.jaas.config={plain}",
        f"listener.name.{listener.lower()}.{SCRAM.lower()}.sasl.jaas.config="
        "org.apache.kafka.common.security.scram.ScramLoginModule required;",
        "listener.name.controller.sasl.enabled.mechanisms=PLAIN",
        f"listener.name.controller.plain.sasl.jaas.config={plain}",
        f"authorizer.class.name={AUTHORIZER}",
        f"super.users=User:{INTERNAL_USER}",
        "allow.everyone.if.no.acl.found=false",
    ]


def new_cluster_id() -> str:
    """A fresh KRaft cluster id: base64url of 16 random bytes, without padding (22 chars).

    Never starting with ``-``: StorageTool would read ``-t -abc...`` as an option (Kafka's own
    ``Uuid.randomUuid`` redraws such ids for the same reason).
    """
    while True:
        cid = base64.urlsafe_b64encode(os.urandom(16)).decode("ascii").rstrip("=")
        if not cid.startswith("-"):
            return cid


def check_cluster_id(text: str) -> str:
    """A KRaft cluster id: 22 base64url characters, not starting with ``-``."""
    if not isinstance(text, str) or not _CLUSTER_ID.fullmatch(text):
        raise ConfigValueError("cluster_id", text, "expected 22 base64url characters, not starting with -")
    return text


def cluster_id(broker_dir: Path, given: str | None = None) -> str:
    """The cluster id kept in ``broker_dir/cluster.id``, created on first use: ``given`` (a
    cluster node's id, derived from the graph) or a new random one. A stored id that differs from
    ``given`` is refused: the node's data belongs to another cluster."""
    path = broker_dir / CLUSTER_ID_FILE
    if given is not None:
        check_cluster_id(given)
    if path.exists():
        text = path.read_text(encoding="ascii").strip()
        if not _CLUSTER_ID.fullmatch(text):
            raise EngineError(
                f"{path}: {text!r} is not a KRaft cluster id",
                hint="delete the broker directory to start over with a new cluster",
            )
        if given is not None and text != given:
            raise EngineError(
                f"{path}: this node's data belongs to KRaft cluster {text}, not {given}",
                hint="the cluster's pk:id or IRI changed, or the node moved to another cluster: "
                     "delete the broker directory (its data is lost) to join the new one",
            )
        return text
    broker_dir.mkdir(parents=True, exist_ok=True)
    text = given or new_cluster_id()
    path.write_text(text + "\n", encoding="ascii")
    return text


def extra_jvm_options(environ: Mapping[str, str] | None = None) -> list[str]:
    """The options :data:`JVM_OPTS_ENV` names (none when unset), each a checked ``-XX:`` flag;
    :class:`ConfigValueError` names the variable and the first option that is not one."""
    text = (os.environ if environ is None else environ).get(JVM_OPTS_ENV, "")
    options = text.split()
    for option in options:
        if not _XX_OPTION.fullmatch(option):
            raise ConfigValueError(JVM_OPTS_ENV, option, "expected HotSpot -XX: options separated by spaces, "
                                                         "e.g. -XX:TieredStopAtLevel=1 -XX:+UseSerialGC")
    return options


def java_options(kafka: KafkaParts, heap: str, log4j: Path | None, logs_dir: Path | None) -> list[str]:
    if not _HEAP.fullmatch(heap):
        raise ConfigValueError("heap", heap, "expected a JVM size such as 512m or 1g")
    opts = [f"-Xmx{heap}", *extra_jvm_options(), "-Djava.awt.headless=true"]
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
    opts = java_options(kafka, "256m", kafka.tools_log4j_config, None)
    return [str(java), *_ONE_SHOT_OPTIONS, *opts, "kafka.tools.StorageTool", "format",
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
    cluster: str | None = None,
) -> str:
    """Format ``cfg.data_dir`` once for the broker dir's cluster id (``cluster``, a cluster node's,
    or one drawn at the first format); return that id.

    Already formatted with the same id: nothing runs. Formatted with another id: refused (Kafka
    would refuse to start on it)."""
    cluster = cluster_id(broker_dir, cluster)
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
    opts = java_options(kafka, heap, kafka.log4j_config, logs_dir)
    return [str(java), *opts, "kafka.Kafka", str(check_path("properties_file", properties_file))]
