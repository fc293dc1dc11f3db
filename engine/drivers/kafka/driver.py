"""The Kafka driver: a single-node KRaft cluster (broker and controller in one JVM).

Config, storage format and command line come from :mod:`engine.drivers.kafka.runtime`. The controller
listener needs a second port the ontology does not model: :meth:`KafkaDriver.prepare` picks a free
one at the first start and keeps it in ``<broker dir>/controller.port`` so restarts reuse it
(``render_config`` reads it there, so it is pure given the folder). Topics are real Kafka topics,
managed and observed with confluent-kafka's AdminClient; a change Kafka cannot make (fewer
partitions, another replication factor) is refused before anything is touched.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

from confluent_kafka import KafkaError, KafkaException
from confluent_kafka.admin import (
    AdminClient,
    AlterConfigOpType,
    ConfigEntry,
    ConfigResource,
    NewPartitions,
    NewTopic,
    ResourceType,
)

from engine import netutil, parts, process
from engine.drivers.kafka import runtime as kafka_runtime
from engine.drivers.base import (
    DATA_DIR,
    KAFKA_TOPIC_FIELDS,
    LOGS_DIR,
    check_topic_fields,
    refuse_bridges,
    spec_essence,
)
from engine.errors import (
    BrokerUnavailableError,
    ConfigValueError,
    DriverError,
    DriverRefusedError,
    EngineError,
    WaitTimeoutError,
)
from engine.model import BridgeSpec, BrokerSpec, ObservedTopic, TopicSpec
from engine.values import check_host, check_port, host_in_url

PROPERTIES_FILE = "server.properties"
CONTROLLER_PORT_FILE = "controller.port"
RETENTION = "retention.ms"
_TOPIC_CHARS = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789._-")

log = logging.getLogger(__name__)


class KafkaDriver:
    """Kafka 3.9 (KRaft) from the jars ``make setup`` installs."""

    kind = "kafka"
    implicit_topics = False
    start_deadline = 90.0
    stop_grace = 30.0

    def __init__(self, *, heap: str = kafka_runtime.DEFAULT_HEAP, admin_timeout: float = 30.0,
                 version: str = parts.KAFKA_VERSION) -> None:
        self.heap = heap
        self.admin_timeout = admin_timeout
        self.version = version

    # --- start -----------------------------------------------------------------------------

    def node_config(self, spec: BrokerSpec, broker_dir: Path) -> kafka_runtime.KafkaNodeConfig:
        return kafka_runtime.KafkaNodeConfig(
            host=spec.host,
            port=spec.port,
            controller_port=read_controller_port(broker_dir),
            data_dir=broker_dir / DATA_DIR,
        )

    def validate(self, spec: BrokerSpec) -> None:
        """The listener values Kafka needs (a wildcard host is refused: it cannot be advertised)."""
        port = check_port("port", spec.port)
        kafka_runtime.KafkaNodeConfig(host=spec.host, port=port, controller_port=1 if port != 1 else 2,
                                      data_dir=Path("/nonexistent/plantkg/broker/data"))

    def render_config(self, spec: BrokerSpec, broker_dir: Path,
                      bridges: tuple[BridgeSpec, ...] = ()) -> dict[str, str]:
        """``server.properties``; needs the controller port that :meth:`prepare` stored. Kafka
        carries no native bridge (MQTT <-> Kafka bridges are workers)."""
        refuse_bridges(self.kind, bridges)
        cfg = self.node_config(spec, broker_dir)
        return {PROPERTIES_FILE: kafka_runtime.render_server_properties(cfg)}

    def command(self, spec: BrokerSpec, broker_dir: Path) -> list[str]:
        return kafka_runtime.broker_command(
            parts.kafka_parts(self.version), parts.java_binary(), broker_dir / PROPERTIES_FILE,
            logs_dir=broker_dir / LOGS_DIR, heap=self.heap,
        )

    def prepare(self, spec: BrokerSpec, broker_dir: Path) -> None:
        """Keep a controller port (picked free once) and format the storage once per folder."""
        host = check_host("host", spec.host)
        check_port("port", spec.port)
        broker_dir.mkdir(parents=True, exist_ok=True)
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
        )

    def health(self, spec: BrokerSpec, timeout: float) -> bool:
        """The broker answers a metadata request and lists itself."""
        try:
            metadata = _admin(spec, quiet=True).list_topics(timeout=max(timeout, 0.1))
        except (KafkaException, ValueError):
            return False
        return bool(metadata.brokers)

    # --- topics ----------------------------------------------------------------------------
    # Every AdminClient future is awaited through _result(), which keeps no reference to the
    # future once it failed: a frame holding the future (whose exception's traceback holds the
    # frame) would keep the AdminClient alive, and reconnecting, until a gc pass.

    def ensure_topic(self, spec: BrokerSpec, topic: TopicSpec) -> ObservedTopic:
        check_kafka_topic_name(topic.name)
        check_topic_fields(topic, self.kind, KAFKA_TOPIC_FIELDS)
        admin = _admin(spec)
        end = time.monotonic() + self.admin_timeout
        current = self._describe(admin, topic.name)
        if current is None and not self._create(admin, topic):
            current = self._describe(admin, topic.name)  # created meanwhile: alter it instead
        if current is not None:
            self._alter(admin, topic, current)
        return self._wait_matching(admin, topic, end)

    def delete_topic(self, spec: BrokerSpec, name: str) -> None:
        check_kafka_topic_name(name)
        admin = _admin(spec)
        _result(admin.delete_topics([name], operation_timeout=self.admin_timeout)[name],
                self.admin_timeout, f"deleting topic {name!r}",
                tolerate=(KafkaError.UNKNOWN_TOPIC_OR_PART,))
        _poll(lambda: self._describe(admin, name) is None, self.admin_timeout,
              f"topic {name!r} to disappear from the metadata")

    def observe_topics(self, spec: BrokerSpec) -> list[ObservedTopic]:
        """Every topic but Kafka's internal ones (``__consumer_offsets``...), as the broker has it."""
        admin = _admin(spec)
        timeout = min(self.admin_timeout, 10.0)  # an agent's GET should not hang on one broker
        metadata = _call(lambda: admin.list_topics(timeout=timeout), "listing topics")
        names = sorted(n for n in metadata.topics if not n.startswith("__"))
        retention = self._retention(admin, names)
        # a topic being deleted is still in the metadata but has no configs any more: it is gone
        return [_observed(metadata.topics[n], retention[n]) for n in names if n in retention]

    def essence(self, spec: BrokerSpec) -> dict[str, Any]:
        return spec_essence(spec)

    # --- helpers ---------------------------------------------------------------------------

    def _describe(self, admin: AdminClient, name: str) -> ObservedTopic | None:
        # All topics, not list_topics(topic=name): a metadata request for one unknown topic
        # auto-creates it on a broker with auto.create.topics.enable (Kafka's default). Ours
        # render it false (runtime.py), but an adopted or hand-edited broker may not.
        metadata = _call(lambda: admin.list_topics(timeout=self.admin_timeout),
                         f"describing topic {name!r}")
        found = metadata.topics.get(name)
        if found is None or found.error is not None and found.error.code() in (
            KafkaError.UNKNOWN_TOPIC_OR_PART, KafkaError._UNKNOWN_TOPIC
        ):
            return None
        retention = self._retention(admin, [name])
        if name not in retention:  # listed, but its configs are gone: deletion in progress
            return None
        return _observed(found, retention[name])

    def _retention(self, admin: AdminClient, names: list[str]) -> dict[str, int | None]:
        """retention.ms per topic; a topic Kafka no longer knows (being deleted) is left out."""
        if not names:
            return {}
        futures = admin.describe_configs([ConfigResource(ResourceType.TOPIC, n) for n in names],
                                         request_timeout=self.admin_timeout)
        result: dict[str, int | None] = {}
        for resource in futures:  # (not popped: confluent-kafka sets them through this dict)
            entries = _result(futures[resource], self.admin_timeout,
                              f"reading the configs of topic {resource.name!r}",
                              tolerate=(KafkaError.UNKNOWN_TOPIC_OR_PART,))
            if entries is _TOLERATED:
                continue
            entry = entries.get(RETENTION)
            result[resource.name] = int(entry.value) if entry is not None and entry.value else None
        return result

    def _create(self, admin: AdminClient, topic: TopicSpec) -> bool:
        """Create ``topic`` (retrying while the broker is not ready); False if it exists."""
        config = {RETENTION: str(topic.retention_ms)} if topic.retention_ms is not None else {}
        new = NewTopic(topic.name, num_partitions=topic.partitions or 1,
                       replication_factor=topic.replication_factor or 1, config=config)

        def attempt() -> str | None:
            try:
                done = _result(
                    admin.create_topics([new], operation_timeout=self.admin_timeout)[topic.name],
                    self.admin_timeout, f"creating topic {topic.name!r}",
                    tolerate=(KafkaError.TOPIC_ALREADY_EXISTS,),
                )
            except BrokerUnavailableError:
                return None
            return "exists" if done is _TOLERATED else "created"

        return _poll(attempt, self.admin_timeout, f"topic {topic.name!r} to be created") == "created"

    def _alter(self, admin: AdminClient, topic: TopicSpec, current: ObservedTopic) -> None:
        """Refuse what Kafka cannot do, then raise partitions and set retention.ms."""
        where = f"topic {topic.name!r}"
        if topic.partitions is not None and current.partitions is not None \
                and topic.partitions < current.partitions:
            raise DriverRefusedError(
                f"{where} has {current.partitions} partitions; Kafka cannot lower them to "
                f"{topic.partitions}",
                hint=f"set pk:partitions to {current.partitions} or more, or delete the topic "
                "(its messages are lost) and create it again",
            )
        if topic.replication_factor is not None and current.replication_factor is not None \
                and topic.replication_factor != current.replication_factor:
            raise DriverRefusedError(
                f"{where} has replication factor {current.replication_factor}; changing it to "
                f"{topic.replication_factor} needs a partition reassignment, which plantkg does not do",
                hint=f"set pk:replicationFactor to {current.replication_factor}, or delete the topic "
                "and create it again",
            )
        if topic.partitions is not None and current.partitions is not None \
                and topic.partitions > current.partitions:
            _result(admin.create_partitions([NewPartitions(topic.name, topic.partitions)],
                                            operation_timeout=self.admin_timeout)[topic.name],
                    self.admin_timeout, f"adding partitions to {where}")
        if topic.retention_ms is not None and topic.retention_ms != current.retention_ms:
            resource = ConfigResource(
                ResourceType.TOPIC, topic.name,
                incremental_configs=[ConfigEntry(RETENTION, str(topic.retention_ms),
                                                 incremental_operation=AlterConfigOpType.SET)],
            )
            _result(admin.incremental_alter_configs([resource])[resource], self.admin_timeout,
                    f"setting {RETENTION} of {where}")

    def _wait_matching(self, admin: AdminClient, topic: TopicSpec, end: float) -> ObservedTopic:
        """Poll the metadata until it shows what was asked (creation and changes propagate)."""
        def matching() -> ObservedTopic | None:
            seen = self._describe(admin, topic.name)
            if seen is None:
                return None
            if topic.partitions is not None and seen.partitions != topic.partitions:
                return None
            if topic.retention_ms is not None and seen.retention_ms != topic.retention_ms:
                return None
            return seen
        return _poll(matching, max(end - time.monotonic(), 1.0), f"topic {topic.name!r} to match")


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


def check_kafka_topic_name(name: object) -> str:
    """Kafka's Topic.validate: 1 to 249 characters of ``[a-zA-Z0-9._-]``, not ``.`` or ``..``."""
    if not isinstance(name, str) or not name:
        raise ConfigValueError("name", name, "a Kafka topic name must be a non-empty string")
    if len(name) > 249 or name in (".", "..") or not set(name) <= _TOPIC_CHARS:
        raise ConfigValueError(
            "name", name, "a Kafka topic name is 1 to 249 characters of A-Z a-z 0-9 . _ - "
            "(not . or .. alone)"
        )
    return name


def _admin(spec: BrokerSpec, *, quiet: bool = False) -> AdminClient:
    bootstrap = f"{host_in_url(check_host('host', spec.host))}:{check_port('port', spec.port)}"
    config: dict[str, Any] = {"bootstrap.servers": bootstrap, "socket.timeout.ms": 10_000}
    # librdkafka prints connection failures to stderr; a probe of a starting broker expects them.
    config["log_level"] = 0 if quiet else 3
    return AdminClient(config)


def _observed(meta: Any, retention_ms: int | None) -> ObservedTopic:
    partitions = meta.partitions
    replicas = {len(p.replicas) for p in partitions.values()}
    return ObservedTopic(
        name=meta.topic,
        partitions=len(partitions),
        replication_factor=max(replicas) if replicas else None,
        retention_ms=retention_ms,
    )


_TOLERATED = object()


def _result(future: Any, timeout: float, doing: str, *, tolerate: tuple[int, ...] = ()) -> Any:
    """``future.result()``; a Kafka error becomes a DriverError (a code in ``tolerate`` gives
    ``_TOLERATED``). The failed future is dropped before raising (see the note on topics)."""
    try:
        return future.result(timeout=timeout)
    except KafkaException as exc:
        error = exc.args[0] if exc.args else None
    except TimeoutError:  # concurrent.futures.TimeoutError is TimeoutError on 3.11
        error = None
    finally:
        del future
    if isinstance(error, KafkaError) and error.code() in tolerate:
        return _TOLERATED
    raise _driver_error(error, doing)


def _driver_error(error: KafkaError | None, doing: str) -> DriverError:
    """A Kafka error as a DriverError: retryable (broker unavailable), refused, or other."""
    if not isinstance(error, KafkaError):
        return BrokerUnavailableError(f"Kafka did not answer in time while {doing}",
                                      hint="the broker may be starting or busy; try again")
    text = f"Kafka error while {doing}: {error.str()} ({error.name()})"
    if error.retriable() or error.code() in (KafkaError._TRANSPORT, KafkaError._TIMED_OUT,
                                              KafkaError._ALL_BROKERS_DOWN):
        return BrokerUnavailableError(text, hint="the broker may be starting; try again")
    if error.code() in (KafkaError.INVALID_REPLICATION_FACTOR, KafkaError.INVALID_PARTITIONS,
                        KafkaError.INVALID_CONFIG, KafkaError.POLICY_VIOLATION,
                        KafkaError.TOPIC_EXCEPTION, KafkaError.INVALID_REQUEST,
                        KafkaError.INVALID_REPLICA_ASSIGNMENT):
        return DriverRefusedError(text, hint="change the topic's settings in the plant")
    return DriverError(text)


def _call(fn: Any, doing: str) -> Any:
    """``fn()`` (a direct AdminClient call such as list_topics) with Kafka errors mapped."""
    try:
        return fn()
    except KafkaException as exc:
        error = exc.args[0] if exc.args else None
    raise _driver_error(error, doing)


def _poll(predicate: Any, budget: float, what: str) -> Any:
    try:
        return process.wait_until(predicate, budget, 0.1, what=what)
    except WaitTimeoutError as exc:
        raise BrokerUnavailableError(str(exc), hint="the broker may be busy; try again") from exc
