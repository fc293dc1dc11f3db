"""The Kafka driver: a KRaft node — alone (broker and controller in one JVM, its own cluster) or
one node of a multi-node cluster (``BrokerSpec.kafka``; engine.derived.kafka_cluster, docs/kafka.md).

Config, storage format and command line come from :mod:`engine.drivers.kafka.runtime`; topics
from :mod:`engine.drivers.kafka.topics`. A node alone needs a controller port the ontology does not
model: :meth:`KafkaDriver.prepare` picks a free one at the first start and keeps it in
``<broker dir>/controller.port`` so restarts reuse it (``render_config`` reads it there, so it is
pure given the folder). A cluster node has its controller port, its quorum and its KRaft cluster
id from the graph, so every node's agent renders and formats alike without talking to the others.

Health: a node alone answers a metadata request; a cluster node with the broker role is
registered and back in the ISR of every partition it holds (so a rolling restart waits for it
before the next node stops, and a node the agent restarted after a crash counts as running once
it caught up); a controller-only node accepts a connection on its quorum listener. A closed node
alone, or a closed cluster's lead node, counts as running once its users and ACLs are as the spec
says (engine.drivers.kafka.access; a cluster's are in its metadata log, shared by all its nodes).

Settling (engine.drivers.base.Settling): the PUT of a closed cluster's lead node answers only once
every broker node of the cluster enforces those users and ACLs (engine.drivers.kafka.spread), so
a client that logs in at any node right after ``plantkg apply`` is let in. Not part of the health
check: the lead stays healthy while another node is down. A node alone needs no such wait.
"""

from __future__ import annotations

import logging
import socket
from pathlib import Path
from typing import Any

from confluent_kafka import KafkaException
from confluent_kafka.admin import AdminClient

from engine import netutil, parts
from engine.drivers.base import (
    DATA_DIR,
    KAFKA_TOPIC_FIELDS,
    LOGS_DIR,
    check_topic_fields,
    refuse_bridges,
    spec_essence,
)
from engine.drivers.kafka import access, spread, tls
from engine.drivers.kafka import runtime as kafka_runtime
from engine.drivers.kafka.topics import Topics, admin_client, check_kafka_topic_name, in_sync
from engine.errors import ConfigValueError, DriverError, EngineError
from engine.model import BridgeSpec, BrokerSpec, ObservedTopic, TopicSpec, to_dict
from engine.security import kafka_client
from engine.values import check_host, check_port, host_in_url

PROPERTIES_FILE = "server.properties"
CONTROLLER_PORT_FILE = "controller.port"

log = logging.getLogger(__name__)

__all__ = ["KafkaDriver", "check_kafka_topic_name", "read_controller_port"]


class KafkaDriver:
    """Kafka 3.9 (KRaft) from the jars ``make setup`` installs."""

    kind = "kafka"
    implicit_topics = False
    start_deadline = 90.0
    stop_grace = 30.0
    #: Seconds the lead's PUT waits for the other nodes to enforce the users and ACLs.
    settle_deadline = 30.0

    def __init__(self, *, heap: str = kafka_runtime.DEFAULT_HEAP, admin_timeout: float = 30.0,
                 version: str = parts.KAFKA_VERSION) -> None:
        self.heap = heap
        self.admin_timeout = admin_timeout
        self.version = version

    # --- start -----------------------------------------------------------------------------

    def node_config(self, spec: BrokerSpec, broker_dir: Path) -> kafka_runtime.KafkaNodeConfig:
        node = spec.kafka
        if node is None:
            return kafka_runtime.KafkaNodeConfig(
                host=spec.host, port=spec.port, controller_port=read_controller_port(broker_dir),
                data_dir=broker_dir / DATA_DIR,
                internal_password=access.internal_password() if access.is_closed(spec) else None,
                tls=tls.node_tls(spec, broker_dir),
            )
        return kafka_runtime.KafkaNodeConfig(
            host=spec.host, port=spec.port,
            controller_port=node.controller_port if node.controller_port is not None else spec.port,
            data_dir=broker_dir / DATA_DIR, node_id=node.node_id, roles=node.roles,
            voters=tuple((v.node_id, v.host, v.port) for v in node.voters),
            replication=node.replication, min_insync=node.min_insync,
            internal_password=access.internal_password() if access.is_closed(spec) else None,
            tls=tls.node_tls(spec, broker_dir),  # the cluster says pk:tls: every node's listeners
        )

    def validate(self, spec: BrokerSpec) -> None:
        """The listener values Kafka needs (a wildcard host is refused: it cannot be advertised)."""
        port = check_port("port", spec.port)
        if spec.kafka is not None:
            self.node_config(spec, Path("/nonexistent/plantkg/broker"))
            kafka_runtime.check_cluster_id(spec.kafka.cluster_id)
            return
        kafka_runtime.KafkaNodeConfig(host=spec.host, port=port, controller_port=1 if port != 1 else 2,
                                      data_dir=Path("/nonexistent/plantkg/broker/data"),
                                      tls=tls.node_tls(spec, Path("/nonexistent/plantkg/broker")))

    def render_config(self, spec: BrokerSpec, broker_dir: Path,
                      bridges: tuple[BridgeSpec, ...] = ()) -> dict[str, str]:
        """``server.properties``; a node alone needs the controller port that :meth:`prepare`
        stored. A closed broker (a closed cluster's lead node) also gets the digest of its users'
        passwords, so a changed password restarts it (engine.drivers.kafka.access); a TLS broker its keystore and
        the plant CA's certificate (engine.drivers.kafka.tls). Kafka carries no native bridge
        (its bridges are workers)."""
        refuse_bridges(self.kind, bridges)
        cfg = self.node_config(spec, broker_dir)
        files = {PROPERTIES_FILE: kafka_runtime.render_server_properties(cfg), **tls.tls_files(spec, broker_dir)}
        if cfg.internal_password is not None and _sets_access(spec):
            files[access.DIGEST_FILE] = access.users_digest(spec.users, cfg.internal_password)
        return files

    def command(self, spec: BrokerSpec, broker_dir: Path) -> list[str]:
        return kafka_runtime.broker_command(
            parts.kafka_parts(self.version), parts.java_binary(), broker_dir / PROPERTIES_FILE,
            logs_dir=broker_dir / LOGS_DIR, heap=self.heap,
        )

    def prepare(self, spec: BrokerSpec, broker_dir: Path) -> None:
        """Format the storage once per folder — a cluster node with its cluster's id, a node alone
        with one drawn at the first start, after keeping a controller port (picked free once)."""
        host = check_host("host", spec.host)
        check_port("port", spec.port)
        broker_dir.mkdir(parents=True, exist_ok=True)
        if not spec.tls:  # no key left behind by a broker that no longer speaks TLS
            (broker_dir / tls.TLS_KEYSTORE_FILE).unlink(missing_ok=True)
        if spec.kafka is None:
            stored = _stored_controller_port(broker_dir)
            if stored is None or stored == spec.port:
                bind = "127.0.0.1" if host == "0.0.0.0" else "::1" if host == "::" else host
                port = next(p for p in netutil.free_ports(2, bind) if p != spec.port)
                (broker_dir / CONTROLLER_PORT_FILE).write_text(f"{port}\n", encoding="ascii")
        files = self.render_config(spec, broker_dir)
        properties = broker_dir / PROPERTIES_FILE
        properties.write_text(files[PROPERTIES_FILE], encoding="utf-8")
        kafka_runtime.format_storage(
            self.node_config(spec, broker_dir), properties, broker_dir,
            kafka=parts.kafka_parts(self.version), java=parts.java_binary(),
            cluster=spec.kafka.cluster_id if spec.kafka is not None else None,
        )

    def health(self, spec: BrokerSpec, timeout: float) -> bool:
        """See the module docstring; never raises."""
        node = spec.kafka
        if node is not None and "broker" not in node.roles:
            return _accepts(spec.host, spec.port, timeout)
        try:
            admin = _admin(spec, quiet=True, own=True)
            metadata = admin.list_topics(timeout=max(timeout, 0.1))
        except (KafkaException, ValueError, EngineError):
            return False
        if node is None and not bool(metadata.brokers) or node is not None and not in_sync(metadata, node.node_id):
            return False
        if access.is_closed(spec) and _sets_access(spec):  # users and ACLs as the spec says
            try:
                access.sync_access(admin, spec.users, max(timeout, 5.0))
            except (DriverError, ConfigValueError) as exc:
                log.warning("broker %s: users and ACLs not set yet: %s", spec.id, exc)
                return False
        return True

    def settle(self, spec: BrokerSpec) -> None:
        """A closed cluster's lead: wait until every broker node of the cluster enforces the
        users and ACLs the lead set (AccessNotSpreadError after :attr:`settle_deadline` s).
        Anything else returns at once: a node alone is one process that applies what it committed
        within moments (and stays as fast as it was), an open cluster has no users, another node
        sets nothing."""
        node = spec.kafka
        if node is None or not node.lead or not access.is_closed(spec):
            return
        settings = kafka_client.client_settings(True, spec.tls)
        login = spread.Login(settings["sasl.password"], settings["sasl.username"], settings.get("ssl.ca.location"))
        spread.wait_every_node(node.cluster, node.bootstrap, spec.users, login, self.settle_deadline)

    # --- topics (engine.drivers.kafka.topics) -----------------------------------------------

    def ensure_topic(self, spec: BrokerSpec, topic: TopicSpec) -> ObservedTopic:
        check_kafka_topic_name(topic.name)
        check_topic_fields(topic, self.kind, KAFKA_TOPIC_FIELDS)
        default = spec.kafka.replication if spec.kafka is not None else None
        with Topics(_admin(spec), self.admin_timeout) as topics:
            return topics.ensure(topic, default)

    def delete_topic(self, spec: BrokerSpec, name: str) -> None:
        check_kafka_topic_name(name)
        with Topics(_admin(spec), self.admin_timeout) as topics:
            topics.delete(name)

    def observe_topics(self, spec: BrokerSpec) -> list[ObservedTopic]:
        """Every topic but the internal ones, as the cluster has it; none from a cluster node
        that is not its lead (the cluster's topics are planned once, on the lead)."""
        if spec.kafka is not None and not spec.kafka.lead:
            return []
        with Topics(_admin(spec), self.admin_timeout) as topics:
            return topics.observe()

    def essence(self, spec: BrokerSpec) -> dict[str, Any]:
        """Kind, address and port; for a cluster node also what its config renders of the
        cluster (not the lead flag or the broker list, which restart nothing)."""
        out = spec_essence(spec)
        if access.is_closed(spec):  # SASL listeners: a change either way restarts the broker
            out["closed"] = True
        if spec.users and _sets_access(spec):  # a password's new content shows in the digest
            out["users"] = [{"name": u.name, "secret_ref": u.secret_ref, "write": sorted(u.write),
                             "read": sorted(u.read)} for u in sorted(spec.users, key=lambda u: u.name)]
        if spec.tls:  # only then: a plain broker's essence, and so its config hash, stays as it was
            out["tls"] = True
        if spec.kafka is not None:
            node = to_dict(spec.kafka)
            out["kafka"] = {k: v for k, v in node.items() if k not in ("lead", "bootstrap")}
        return out

    def tls_renewal(self, spec: BrokerSpec, broker_dir: Path) -> str | None:
        """Why a TLS broker's certificate must be issued again (None: current, or plain); the
        agent reports it, the plan turns it into an update, the PUT renders a new one."""
        return tls.renewal(spec, broker_dir)


def _sets_access(spec: BrokerSpec) -> bool:
    """This node sets the users and ACLs: a node alone, or a cluster's lead node. A cluster keeps
    them in its metadata log, shared by every node, so they are set once for all, and only the
    lead's machine reads the users' passwords (a change of users restarts the lead only)."""
    return spec.kafka is None or spec.kafka.lead


def read_controller_port(broker_dir: Path) -> int:
    """The controller port :meth:`KafkaDriver.prepare` stored in the broker folder."""
    port = _stored_controller_port(broker_dir)
    if port is None:
        raise EngineError(
            f"{broker_dir / CONTROLLER_PORT_FILE} is missing",
            hint="the agent creates it when it first starts the broker (KafkaDriver.prepare)",
        )
    return port


def _stored_controller_port(broker_dir: Path) -> int | None:
    path = broker_dir / CONTROLLER_PORT_FILE
    try:
        text = path.read_text(encoding="ascii").strip()
    except FileNotFoundError:
        return None
    if not text.isdigit():
        raise ConfigValueError("controller_port", text, f"{path} must hold a port number")
    return check_port("controller_port", int(text))


def _admin(spec: BrokerSpec, *, quiet: bool = False, own: bool = False) -> AdminClient:
    """An AdminClient of the broker, or of every broker node of its cluster (``own``: of this
    node's listener only, for its health)."""
    here = f"{host_in_url(check_host('host', spec.host))}:{check_port('port', spec.port)}"
    bootstrap = spec.kafka.bootstrap if spec.kafka is not None and spec.kafka.bootstrap and not own else (here,)
    return admin_client(bootstrap, quiet=quiet, extra=kafka_client.client_settings(access.is_closed(spec), spec.tls))


def _accepts(host: str, port: int, timeout: float) -> bool:
    """A TCP connection to ``host:port`` succeeds within ``timeout`` s."""
    try:
        with socket.create_connection((host, port), timeout=max(timeout, 0.1)):
            return True
    except OSError:
        return False
