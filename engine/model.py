"""The engine's data: desired state, observed state and the plan between them.

Every stage after the knowledge graph passes these frozen dataclasses, and nothing else, to the
next: ``derive`` builds a :class:`DesiredState` from the reasoned graph, agents report an
:class:`ObservedState`, ``plan`` turns the two into a :class:`Plan` of :class:`Change` s, ``apply``
sends the changes to agents. They are plain values (hashable, comparable, JSON-able through
``to_dict``/``from_dict``) so each stage can be tested alone and plans can be kept as files.

Only the fields the ontology models are compared when planning (the *essence* of a broker or a
topic); pids, start times and restart counts are observed but never cause a change.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, fields
from functools import cached_property
from typing import Any, Mapping


class BrokerStatus(str, enum.Enum):
    """What an agent says about one broker process."""

    RUNNING = "running"          # process alive and health check passed
    STARTING = "starting"        # process alive, health check not yet passed
    STOPPED = "stopped"          # not running, on purpose
    STOPPED_BY_OPERATOR = "stopped-by-operator"  # `plantkg stop`: kept stopped until started
    CRASHED = "crashed"          # exited unexpectedly; the agent will restart it (with backoff)
    FAILED = "failed"            # could not be started (bad config, port in use, ...)


class Action(str, enum.Enum):
    """What a change does to one object (Terraform's vocabulary)."""

    NOOP = "no-op"
    CREATE = "create"
    UPDATE = "update"
    REPLACE = "replace"
    DELETE = "delete"


@dataclass(frozen=True)
class BrokerUser:
    """A client the broker admits, with what it may do: a resource of the plant that sends to the
    broker and has a ``pk:secretRef``, a ``pk:clientCertificate true``, or both (derive).
    ``secret_ref`` says where its password is on the broker's machine — ``env:NAME`` or
    ``file:/absolute/path`` — never the password itself; the broker's agent reads it when it
    renders the broker's files. None: no password, it logs in only with a plant-CA client
    certificate (``certificate``) on the broker's certificate listener (``certificate_port``).
    ``write``/``read``: the topic names it may publish / subscribe to on this broker
    (``pk:mayWrite``/``pk:mayRead``, which ``pk:publishes``/``pk:subscribes`` imply), sorted; on
    a context broker, the entity ids of those topics."""

    name: str                     # the resource's pk:id: its user name on the broker
    secret_ref: str | None = None  # None: a certificate user without a password
    write: tuple[str, ...] = ()
    read: tuple[str, ...] = ()
    certificate: bool = False     # pk:clientCertificate: may log in with a plant-CA client certificate


@dataclass(frozen=True)
class KafkaVoter:
    """A voter of a KRaft controller quorum: ``node_id@host:port`` in controller.quorum.voters."""

    node_id: int
    host: str
    port: int                # its controller listener


@dataclass(frozen=True)
class KafkaNode:
    """A broker's place in a multi-node Kafka cluster (``pk:nodeOf``; engine.derived.kafka_cluster).

    ``cluster_id`` is the KRaft cluster id every node is formatted with, derived from the
    cluster's IRI (the same on every machine and after every restart). ``lead``: this node's
    agent creates and changes the cluster's topics and carries its bridges (the broker-role node
    with the smallest node id); ``bootstrap``: ``host:port`` of every broker-role node, for clients.
    Neither is rendered into the node's config, so neither restarts it."""

    cluster: str                         # the cluster's pk:id
    cluster_id: str                      # KRaft cluster.id (22 base64url characters)
    node_id: int                         # pk:nodeId
    roles: tuple[str, ...]               # pk:kafkaRole, sorted: "broker", "controller"
    voters: tuple[KafkaVoter, ...]       # the quorum (rule K1), sorted by node id
    controller_port: int | None = None   # pk:controllerPort of a combined node
    replication: int = 1                 # internal topics' replication factor: min(3, brokers)
    min_insync: int | None = None        # the cluster's pk:minInsyncReplicas (a default)
    bootstrap: tuple[str, ...] = ()
    lead: bool = False


@dataclass(frozen=True)
class BrokerSpec:
    """A broker that must exist: what the ontology says of it (its essence)."""

    id: str                 # pk:id — the broker's address in plans and on its agent
    iri: str                # the individual in the graph
    name: str
    kind: str               # pk:brokerType — also the driver's entry-point name
    host: str               # pk:ip — the agent is found there
    port: int               # pk:port
    persist_every: int | None = None  # pk:persistEvery — Mosquitto saves after this many changes
    allow_anonymous: bool | None = None  # pk:allowAnonymous — a context broker takes writes without
                                         # its agent's token (derive: false for a context broker)
    mqtt_port: int | None = None  # pk:mqttPort — the MQTT listener of a broker whose pk:port speaks
                                  # another protocol (a plugin's broker type); bridges connect to it
    users: tuple[BrokerUser, ...] = ()  # the clients it admits and their ACLs (sorted by name); a
                                        # broker with users is closed to anonymous clients unless
                                        # the plant says pk:allowAnonymous true
    tls: bool = False       # pk:tls — the listener speaks TLS only (a plant-CA certificate)
    certificate_port: int | None = None  # pk:certificatePort — a Mosquitto's second TLS listener,
                                         # for clients with a plant-CA client certificate
    kafka: KafkaNode | None = None  # a node of a multi-node Kafka cluster (None: a broker of its own)
    closed_kafkas: tuple[str, ...] = ()  # a context broker: the plant's closed Kafka brokers
    tls_kafkas: tuple[str, ...] = ()  # a context broker: the plant's Kafka brokers that speak TLS
                                         # ("host:port", sorted); its kafka:// notifications log in
                                         # there as plantkg's own principal (engine.derived.access)

    @property
    def address(self) -> str:
        return f"broker.{self.id}"


@dataclass(frozen=True)
class TopicSpec:
    """A topic that must exist on one broker, with the settings that apply to that broker's kind."""

    broker_id: str
    name: str               # pk:name of the topic — the name on the wire
    iri: str
    partitions: int | None = None          # Kafka
    replication_factor: int | None = None  # Kafka
    retention_ms: int | None = None        # Kafka
    qos: int | None = None                 # MQTT
    retain: bool | None = None             # MQTT
    entity_id: str | None = None           # NGSI-v2 context broker: the topic's entity
    entity_type: str | None = None         # NGSI-v2 context broker
    min_insync_replicas: int | None = None  # Kafka (min.insync.replicas)

    @property
    def address(self) -> str:
        return f"topic.{self.broker_id}.{self.name}"


class BridgeMechanism(str, enum.Enum):
    """How a bridge runs; chosen from the inferred classes of its two brokers (engine.derive)."""

    MOSQUITTO = "mosquitto"   # Mosquitto's own bridge, in the carrying broker's mosquitto.conf
    WORKER = "mqtt-kafka"     # a bridge worker process (engine.bridge_worker) run by the carrying agent
    NGSI = "mqtt-ngsi"        # an MQTT <-> NGSI-v2 bridge worker (the paper's FIROS role), run beside
                              # the MQTT broker: messages become entity attributes, and back through a
                              # subscription whose notifications the context broker publishes on MQTT
    MIRROR = "kafka-mirror"   # Kafka -> Kafka: a MirrorMaker 2 supervised like a worker, run by the
                              # agent of the target cluster's lead node (engine.drivers.kafka.mirror)


class BridgeDirection(str, enum.Enum):
    """Where a bridged topic flows, seen from the carrying (local) broker."""

    OUT = "out"     # local -> remote (for a worker: MQTT -> Kafka)
    IN = "in"       # remote -> local (for a worker: Kafka -> MQTT)
    BOTH = "both"


class BridgeStatus(str, enum.Enum):
    """What an agent says about one bridge."""

    RUNNING = "running"        # forwarding: connected to both brokers
    CONNECTING = "connecting"  # alive, not (yet) connected to both ends; it keeps trying
    STOPPED = "stopped"        # not running, on purpose (its broker is stopped)
    CRASHED = "crashed"        # the worker exited unexpectedly; the agent restarts it (backoff)
    FAILED = "failed"          # could not be started


@dataclass(frozen=True)
class BridgeEnd:
    """A broker at one end of a bridge: what the bridge needs to reach it."""

    id: str
    kind: str
    host: str
    port: int
    bootstrap: tuple[str, ...] = ()  # a Kafka cluster: host:port of each of its broker nodes
    tls: bool = False       # the broker's listener speaks TLS: connect with it, verify with the plant CA
    closed: bool = False    # a Kafka that authenticates every client: a worker or MirrorMaker 2 logs in as plantkg


@dataclass(frozen=True)
class BridgeRoute:
    """One topic a bridge forwards. The topic has the same ``pk:name`` on both brokers (the
    MQTT <-> Kafka topic mapping is the identity); ``key`` is how MQTT -> Kafka records are keyed."""

    topic: str
    direction: BridgeDirection
    qos: int = 1                 # MQTT QoS the bridge uses for this topic (pk:qos, default 1)
    key: str = "mqtt-topic"      # pk:kafkaKey: "mqtt-topic" (order kept per topic) or "none"
    entity_id: str | None = None    # NGSI bridge: the entity the topic is (pk:entityId, defaults applied)
    entity_type: str | None = None  # NGSI bridge: its type (pk:entityType, default "Thing")


@dataclass(frozen=True)
class BridgeSpec:
    """Forwarding between two brokers, both directions of the pair in one spec, carried by the
    agent of ``local`` (the source of a one-way Mosquitto bridge, the MQTT end of a worker)."""

    local: BridgeEnd
    remote: BridgeEnd
    mechanism: BridgeMechanism
    routes: tuple[BridgeRoute, ...]   # sorted by topic
    asserted: bool = True             # some direction asserted with pk:bridgesTo, else derived

    @property
    def address(self) -> str:
        return f"bridge.{self.local.id}.{self.remote.id}"


@dataclass(frozen=True)
class DesiredState:
    """Everything the plant needs, sorted by address so equal plants give equal values."""

    brokers: tuple[BrokerSpec, ...] = ()
    topics: tuple[TopicSpec, ...] = ()
    bridges: tuple[BridgeSpec, ...] = ()
    owner: str | None = None  # the plant that owns what it deploys (engine.owner); None: no
                              # owner declared, only things nobody owns are the plant's (as before)

    def broker(self, broker_id: str) -> BrokerSpec | None:
        return self._brokers_by_id.get(broker_id)

    def topics_of(self, broker_id: str) -> tuple[TopicSpec, ...]:
        return self._topics_by_broker.get(broker_id, ())

    # Indexes built once (a frozen dataclass may still fill its __dict__): planning a plant with
    # 500 brokers and 11k topics looked brokers up 11k times, 0.34 s of linear scans.
    @cached_property
    def _brokers_by_id(self) -> dict[str, BrokerSpec]:
        return {b.id: b for b in self.brokers}

    @cached_property
    def _topics_by_broker(self) -> dict[str, tuple[TopicSpec, ...]]:
        found: dict[str, list[TopicSpec]] = {}
        for t in self.topics:
            found.setdefault(t.broker_id, []).append(t)
        return {k: tuple(v) for k, v in found.items()}


@dataclass(frozen=True)
class ObservedTopic:
    """A topic as the broker (Kafka) or the agent's record (MQTT) reports it."""

    name: str
    partitions: int | None = None
    replication_factor: int | None = None
    retention_ms: int | None = None
    qos: int | None = None
    retain: bool | None = None
    entity_id: str | None = None
    entity_type: str | None = None
    owner: str | None = None  # the plant that owns the topic on its agent (None: nobody)
    min_insync_replicas: int | None = None


@dataclass(frozen=True)
class ObservedBroker:
    """One broker as its agent reports it: the essence it runs, plus volatile facts."""

    spec: BrokerSpec
    status: BrokerStatus
    topics: tuple[ObservedTopic, ...] = ()
    pid: int | None = None
    started_at: float | None = None       # seconds since the epoch
    restarts: int = 0
    config_hash: str | None = None
    last_error: str | None = None
    owner: str | None = None              # the plant that owns it on its agent (None: nobody)
    tls_renew: str | None = None          # why its TLS certificate must be issued again (the
                                          # agent's check, e.g. "expires 2027-02-26"); None: current


@dataclass(frozen=True)
class ObservedBridge:
    """One bridge as the agent of its local broker reports it."""

    spec: BridgeSpec
    status: BridgeStatus
    pid: int | None = None              # the worker's (None for a Mosquitto bridge)
    started_at: float | None = None
    restarts: int = 0
    forwarded: int | None = None        # messages forwarded (None: the mechanism does not count)
    retried: int | None = None
    last_error: str | None = None
    refused: int | None = None          # messages the remote refused (mqtt-ngsi: a 4xx), acknowledged
    owner: str | None = None            # the plant that owns it on its agent (None: nobody)
    forwarded_per_s: float | None = None  # messages/s over the worker's last ~10 s (None: not counted)
    lag: int | None = None              # kafka-mirror: records on the source not yet on the target


@dataclass(frozen=True)
class ObservedState:
    """What runs: every broker and bridge reported by the agents that answered; ``unreachable``
    hosts did not."""

    brokers: tuple[ObservedBroker, ...] = ()
    unreachable: tuple[str, ...] = ()
    bridges: tuple[ObservedBridge, ...] = ()

    def bridge(self, address: str) -> ObservedBridge | None:
        return self._bridges_by_address.get(address)

    @cached_property
    def _bridges_by_address(self) -> dict[str, ObservedBridge]:
        return {b.spec.address: b for b in self.bridges}

    def broker(self, broker_id: str) -> ObservedBroker | None:
        return self._by_id.get(broker_id)

    @cached_property
    def _by_id(self) -> dict[str, ObservedBroker]:
        found: dict[str, ObservedBroker] = {}
        for b in self.brokers:
            found.setdefault(b.spec.id, b)  # the first reported, as a linear search would give
        return found


@dataclass(frozen=True)
class Change:
    """One planned change: ``before``/``after`` are the essences (None when absent).

    ``reason`` is for people only; no decision is taken on it.
    """

    address: str
    action: Action
    before: Mapping[str, Any] | None
    after: Mapping[str, Any] | None
    reason: str = ""


@dataclass(frozen=True)
class Refusal:
    """A change the plant asks for that a broker cannot make (e.g. fewer Kafka partitions)."""

    address: str
    reason: str


@dataclass(frozen=True)
class Foreign:
    """Something an agent runs that the plant does not own: shown in the plan, never changed.
    ``owner`` is the plant that owns it, None when nobody does (``--prune`` deletes those)."""

    address: str
    owner: str | None
    reason: str = ""


@dataclass(frozen=True)
class Plan:
    """Ordered changes (brokers, then topics, then bridges; deletes last), refusals, and the
    foreign things the plan leaves alone."""

    changes: tuple[Change, ...] = ()
    refusals: tuple[Refusal, ...] = ()
    unreachable: tuple[str, ...] = ()
    foreign: tuple[Foreign, ...] = ()
    warnings: tuple[str, ...] = ()   # for people: e.g. brokers open to anonymous clients

    @property
    def pending(self) -> tuple[Change, ...]:
        """The changes that do something."""
        return tuple(c for c in self.changes if c.action is not Action.NOOP)

    @property
    def empty(self) -> bool:
        return not self.pending

    @property
    def applicable(self) -> bool:
        """Refusals or agents that did not answer make a plan not applicable as a whole."""
        return not self.refusals and not self.unreachable


def to_dict(value: Any) -> Any:
    """A dataclass (or tuple/list of them) as JSON-able data; enums become their values."""
    if hasattr(value, "__dataclass_fields__"):
        return {f.name: to_dict(getattr(value, f.name)) for f in fields(value)}
    if isinstance(value, enum.Enum):
        return value.value
    if isinstance(value, (list, tuple)):
        return [to_dict(v) for v in value]
    if isinstance(value, Mapping):
        return {k: to_dict(v) for k, v in value.items()}
    return value


