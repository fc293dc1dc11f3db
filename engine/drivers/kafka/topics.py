"""Kafka topics through confluent-kafka's AdminClient: create, change, delete, observe; and the
cluster facts the driver's health reads (which brokers are registered, which replicas in sync).

A topic's settings are Kafka's: partitions and replication factor (the topic's shape) and two
topic configs, ``retention.ms`` and ``min.insync.replicas`` (:data:`CONFIGS`). A change Kafka
cannot make (fewer partitions, another replication factor) is refused before anything is touched.
On a cluster, a topic is created once all the brokers its replication factor needs are registered
(the nodes of a new cluster start in parallel and join one by one).

Every AdminClient future is awaited through :func:`result`, which keeps no reference to the
future once it failed: a frame holding the future (whose exception's traceback holds the frame)
would keep the AdminClient alive, and reconnecting, until a gc pass.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
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

from engine import process
from engine.errors import (
    BrokerUnavailableError,
    ConfigValueError,
    DriverError,
    DriverRefusedError,
    WaitTimeoutError,
)
from engine.model import ObservedTopic, TopicSpec

#: TopicSpec field -> Kafka topic config.
CONFIGS = {"retention_ms": "retention.ms", "min_insync_replicas": "min.insync.replicas"}
RETENTION = CONFIGS["retention_ms"]
_TOPIC_CHARS = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789._-")
_TOLERATED = object()


def admin_client(bootstrap: Sequence[str], *, quiet: bool = False,
                 extra: dict[str, Any] | None = None) -> AdminClient:
    """An AdminClient of the brokers at ``bootstrap`` (``host:port``, checked by the caller);
    ``extra``: more librdkafka settings (a closed Kafka's SASL)."""
    config: dict[str, Any] = {"bootstrap.servers": ",".join(bootstrap), "socket.timeout.ms": 10_000,
                              **(extra or {})}
    # librdkafka prints connection failures to stderr; a probe of a starting broker expects them.
    config["log_level"] = 0 if quiet else 3
    return AdminClient(config)


def is_internal(name: str) -> bool:
    """Kafka's own topics (``__consumer_offsets``...) and MirrorMaker 2's (``mm2-offsets.x.internal``,
    ``x.checkpoints.internal``...: MirrorClient's convention, names ending in ``.internal``; and
    ``heartbeats``, which its heartbeat connector creates on the target even with heartbeats off —
    MirrorClient.isHeartbeatTopic — so a plan showed it as a foreign topic ``--prune`` would delete)."""
    return name.startswith("__") or name.endswith(".internal") or name == "heartbeats" or name.endswith(".heartbeats")


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


class Topics:
    """The topic verbs on one AdminClient, each bounded by ``timeout`` seconds. Use it as a
    context manager: leaving it drops the client (:meth:`close`)."""

    def __init__(self, admin: AdminClient, timeout: float) -> None:
        self.admin: Any = admin
        self.timeout = timeout

    def __enter__(self) -> Topics:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        """Drop the AdminClient now. A failed call's traceback holds frames that hold this object
        (and an agent may keep that error, or a reference cycle through it, for a while): the
        client would live on with it, its threads reconnecting every second to brokers perhaps
        deleted since. Without the last reference librdkafka destroys it at once."""
        self.admin = _Closed()

    def ensure(self, topic: TopicSpec, default_replication: int | None = None) -> ObservedTopic:
        """Create or change ``topic``; wait until the metadata shows it as asked.
        ``default_replication``: a cluster's default replication factor, which a topic that sets
        none gets (None: a broker of its own, one replica)."""
        end = time.monotonic() + self.timeout
        current = self.describe(topic.name)
        if current is None:
            self.wait_brokers(topic.replication_factor or default_replication or 1)
            if not self._create(topic, default_replication is not None):
                current = self.describe(topic.name)  # created meanwhile: change it instead
        if current is not None:
            self._alter(topic, current)
        return self._wait_matching(topic, end)

    def delete(self, name: str) -> None:
        result(self.admin.delete_topics([name], operation_timeout=self.timeout)[name],
               self.timeout, f"deleting topic {name!r}", tolerate=(KafkaError.UNKNOWN_TOPIC_OR_PART,))
        poll(lambda: self.describe(name) is None, self.timeout,
             f"topic {name!r} to disappear from the metadata")

    def observe(self) -> list[ObservedTopic]:
        """Every topic but the internal ones, as the cluster has it."""
        timeout = min(self.timeout, 10.0)  # an agent's GET should not hang on one broker
        metadata = call(lambda: self.admin.list_topics(timeout=timeout), "listing topics")
        names = sorted(n for n in metadata.topics if not is_internal(n))
        configs = self.configs(names)
        # a topic being deleted is still in the metadata but has no configs any more: it is gone
        return [observed(metadata.topics[n], configs[n]) for n in names if n in configs]

    def describe(self, name: str) -> ObservedTopic | None:
        # All topics, not list_topics(topic=name): a metadata request for one unknown topic
        # auto-creates it on a broker with auto.create.topics.enable (Kafka's default). Ours
        # render it false (runtime.py), but an adopted or hand-edited broker may not.
        metadata = call(lambda: self.admin.list_topics(timeout=self.timeout), f"describing topic {name!r}")
        found = metadata.topics.get(name)
        if found is None or found.error is not None and found.error.code() in (
            KafkaError.UNKNOWN_TOPIC_OR_PART, KafkaError._UNKNOWN_TOPIC
        ):
            return None
        configs = self.configs([name])
        if name not in configs:  # listed, but its configs are gone: deletion in progress
            return None
        return observed(found, configs[name])

    def configs(self, names: list[str]) -> dict[str, dict[str, int | None]]:
        """The :data:`CONFIGS` of each topic (by TopicSpec field); a topic Kafka no longer
        knows (being deleted) is left out."""
        if not names:
            return {}
        futures = self.admin.describe_configs([ConfigResource(ResourceType.TOPIC, n) for n in names],
                                              request_timeout=self.timeout)
        out: dict[str, dict[str, int | None]] = {}
        for resource in futures:  # (not popped: confluent-kafka sets them through this dict)
            entries = result(futures[resource], self.timeout,
                             f"reading the configs of topic {resource.name!r}",
                             tolerate=(KafkaError.UNKNOWN_TOPIC_OR_PART,))
            if entries is _TOLERATED:
                continue
            out[resource.name] = {field: _int_entry(entries.get(key)) for field, key in CONFIGS.items()}
        return out

    def wait_brokers(self, count: int) -> None:
        """Until the cluster has ``count`` registered brokers (a replication factor needs them)."""
        if count <= 1:
            return
        poll(lambda: len(call(lambda: self.admin.list_topics(timeout=self.timeout),
                              "listing brokers").brokers) >= count or None,
             self.timeout, f"{count} Kafka brokers to be registered")

    def _create(self, topic: TopicSpec, cluster: bool = False) -> bool:
        """Create ``topic`` (retrying while the broker is not ready); False if it exists. On a
        cluster a topic without a replication factor takes the brokers' default (-1)."""
        config = {key: str(getattr(topic, field)) for field, key in CONFIGS.items()
                  if getattr(topic, field) is not None}
        new = NewTopic(topic.name, num_partitions=topic.partitions or 1,
                       replication_factor=topic.replication_factor or (-1 if cluster else 1), config=config)

        def attempt() -> str | None:
            try:
                done = result(self.admin.create_topics([new], operation_timeout=self.timeout)[topic.name],
                              self.timeout, f"creating topic {topic.name!r}",
                              tolerate=(KafkaError.TOPIC_ALREADY_EXISTS,))
            except BrokerUnavailableError:
                return None
            return "exists" if done is _TOLERATED else "created"

        return poll(attempt, self.timeout, f"topic {topic.name!r} to be created") == "created"

    def _alter(self, topic: TopicSpec, current: ObservedTopic) -> None:
        """Refuse what Kafka cannot do, then raise partitions and set the configs."""
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
            result(self.admin.create_partitions([NewPartitions(topic.name, topic.partitions)],
                                                operation_timeout=self.timeout)[topic.name],
                   self.timeout, f"adding partitions to {where}")
        changed = [ConfigEntry(key, str(getattr(topic, field)), incremental_operation=AlterConfigOpType.SET)
                   for field, key in CONFIGS.items()
                   if getattr(topic, field) is not None and getattr(topic, field) != getattr(current, field)]
        if changed:
            resource = ConfigResource(ResourceType.TOPIC, topic.name, incremental_configs=changed)
            result(self.admin.incremental_alter_configs([resource])[resource], self.timeout,
                   f"setting {', '.join(e.name for e in changed)} of {where}")

    def _wait_matching(self, topic: TopicSpec, end: float) -> ObservedTopic:
        """Poll the metadata until it shows what was asked (creation and changes propagate)."""
        def matching() -> ObservedTopic | None:
            seen = self.describe(topic.name)
            if seen is None:
                return None
            if topic.partitions is not None and seen.partitions != topic.partitions:
                return None
            if any(getattr(topic, f) is not None and getattr(seen, f) != getattr(topic, f) for f in CONFIGS):
                return None
            return seen
        return poll(matching, max(end - time.monotonic(), 1.0), f"topic {topic.name!r} to match")


class _Closed:
    """The client of a closed :class:`Topics`: any use is a bug, said as such."""

    def __getattr__(self, name: str) -> Any:
        raise RuntimeError(f"Topics used after close ({name})")


def in_sync(metadata: Any, node_id: int) -> bool:
    """``node_id`` is a registered broker and in the ISR of every partition it is a replica of."""
    if node_id not in metadata.brokers:
        return False
    return all(node_id in p.isrs for t in metadata.topics.values() for p in t.partitions.values()
               if node_id in p.replicas)


def observed(meta: Any, configs: dict[str, int | None]) -> ObservedTopic:
    partitions = meta.partitions
    replicas = {len(p.replicas) for p in partitions.values()}
    return ObservedTopic(name=meta.topic, partitions=len(partitions),
                         replication_factor=max(replicas) if replicas else None, **configs)


def _int_entry(entry: Any) -> int | None:
    return int(entry.value) if entry is not None and entry.value else None


def result(future: Any, timeout: float, doing: str, *, tolerate: tuple[int, ...] = ()) -> Any:
    """``future.result()``; a Kafka error becomes a DriverError (a code in ``tolerate`` gives
    ``_TOLERATED``). The failed future is dropped before raising (see the module docstring)."""
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
    raise driver_error(error, doing)


def driver_error(error: KafkaError | None, doing: str) -> DriverError:
    """A Kafka error as a DriverError: retryable (broker unavailable), refused, or other."""
    if not isinstance(error, KafkaError):
        return BrokerUnavailableError(f"Kafka did not answer in time while {doing}",
                                      hint="the broker may be starting or busy; try again")
    text = f"Kafka error while {doing}: {error.str()} ({error.name()})"
    # _DESTROY_BROKER: librdkafka (>= 2.10) drops the bootstrap connections once it has learned
    # the cluster's brokers, failing what was in flight on them: a new client of a cluster meets it.
    if error.retriable() or error.code() in (KafkaError._TRANSPORT, KafkaError._TIMED_OUT,
                                              KafkaError._ALL_BROKERS_DOWN, KafkaError._DESTROY_BROKER):
        return BrokerUnavailableError(text, hint="the broker may be starting; try again")
    if error.code() in (KafkaError.INVALID_REPLICATION_FACTOR, KafkaError.INVALID_PARTITIONS,
                        KafkaError.INVALID_CONFIG, KafkaError.POLICY_VIOLATION,
                        KafkaError.TOPIC_EXCEPTION, KafkaError.INVALID_REQUEST,
                        KafkaError.INVALID_REPLICA_ASSIGNMENT):
        return DriverRefusedError(text, hint="change the topic's settings in the plant")
    return DriverError(text)


def call(fn: Callable[[], Any], doing: str) -> Any:
    """``fn()`` (a direct AdminClient call such as list_topics) with Kafka errors mapped."""
    try:
        return fn()
    except KafkaException as exc:
        error = exc.args[0] if exc.args else None
    raise driver_error(error, doing)


def poll(predicate: Callable[[], Any], budget: float, what: str) -> Any:
    try:
        return process.wait_until(predicate, budget, 0.1, what=what)
    except WaitTimeoutError as exc:
        raise BrokerUnavailableError(str(exc), hint="the broker may be busy; try again") from exc
