"""The flows of a plant: for each resource that publishes a topic on a broker, every broker that
must carry that topic — the publishing broker, then each broker the derived bridges' routes reach
from it, following chains (A -> B -> C) — with the bridges that feed each broker.

Pure: a :class:`~engine.model.DesiredState` and the plant's :class:`Publication` s in, frozen
:class:`Flow` s out; no graph, no network. A broker reached by two bridges of the flow lists both
in ``via`` (two paths may deliver the same messages twice: ``--probe`` counts them).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from engine.model import BridgeDirection, BridgeSpec, DesiredState
from engine.security import kafka_client

#: Broker kinds whose topics ``check`` can watch (MQTT subscribe, Kafka consumer). A context broker
#: ("ngsi-v2") keeps entities, not a message stream, and a plugin's kind is unknown here: their stops
#: are listed as not checked, never passed.
WATCHABLE_KINDS = frozenset({"mosquitto", "kafka"})


@dataclass(frozen=True)
class Publication:
    """A resource publishing ``topic`` (its ``pk:name``, the name on the wire) on broker ``broker``."""

    resource_id: str
    resource: str   # pk:name, for people (the id when the plant gives no name)
    topic: str
    broker: str     # the broker's pk:id


@dataclass(frozen=True)
class Link:
    """A bridge that carries the flow's topic into a broker, from ``source``."""

    source: str      # the broker id the bridge takes the topic from
    bridge: str      # the bridge's plan address, bridge.<local>.<remote>
    mechanism: str   # BridgeMechanism value: mosquitto, mqtt-kafka, mqtt-ngsi


@dataclass(frozen=True)
class Stop:
    """One broker a flow must reach; ``via`` is empty for the publishing broker."""

    broker: str
    kind: str
    host: str
    port: int
    hops: int                   # bridges from the publishing broker (0: the source)
    via: tuple[Link, ...] = ()  # every bridge of the flow that delivers the topic here
    tls: bool = False           # the broker's listener speaks TLS (pk:tls)
    closed: bool = False        # a Kafka that admits only its users: taps and probes log in as plantkg

    @property
    def watchable(self) -> bool:
        return self.kind in WATCHABLE_KINDS


@dataclass(frozen=True)
class Flow:
    """One resource's topic and every broker that must carry it, the source first."""

    resource_id: str
    resource: str
    topic: str
    stops: tuple[Stop, ...]   # source first, then by hops and broker id

    @property
    def source(self) -> Stop:
        return self.stops[0]

    @property
    def downstream(self) -> tuple[Stop, ...]:
        return self.stops[1:]


def edges(bridges: tuple[BridgeSpec, ...], topic: str) -> list[tuple[str, str, Link]]:
    """(from broker, to broker, link) for every direction of every bridge route carrying ``topic``."""
    found = []
    for bridge in bridges:
        for route in bridge.routes:
            if route.topic != topic:
                continue
            ends = []
            if route.direction in (BridgeDirection.OUT, BridgeDirection.BOTH):
                ends.append((bridge.local.id, bridge.remote.id))
            if route.direction in (BridgeDirection.IN, BridgeDirection.BOTH):
                ends.append((bridge.remote.id, bridge.local.id))
            for src, dst in ends:
                found.append((src, dst, Link(src, bridge.address, bridge.mechanism.value)))
    return found


def flow_of(desired: DesiredState, publication: Publication) -> Flow | None:
    """The flow of one publication; None when the plant has no such broker."""
    source = desired.broker(publication.broker)
    if source is None:
        return None
    links = edges(desired.bridges, publication.topic)
    hops = {source.id: 0}
    queue = deque([source.id])
    while queue:  # breadth first: each broker at its fewest bridges from the source
        here = queue.popleft()
        for src, dst, _ in links:
            if src == here and dst not in hops and desired.broker(dst) is not None:
                hops[dst] = hops[here] + 1
                queue.append(dst)
    stops = []
    for broker_id, count in sorted(hops.items(), key=lambda item: (item[1], item[0] != source.id, item[0])):
        spec = desired.broker(broker_id)
        assert spec is not None
        via = () if broker_id == source.id else tuple(sorted(
            {link for src, dst, link in links if dst == broker_id and src in hops},
            key=lambda link: (link.source, link.bridge)))
        stops.append(Stop(spec.id, spec.kind, spec.host, spec.port, count, via, tls=spec.tls,
                          closed=kafka_client.is_closed(spec)))
    return Flow(publication.resource_id, publication.resource, publication.topic, tuple(stops))


def derive_flows(desired: DesiredState, publications: list[Publication] | tuple[Publication, ...]) -> tuple[Flow, ...]:
    """Every flow of the plant, sorted by resource, topic and source broker (duplicates merged)."""
    flows = {flow_of(desired, p) for p in set(publications)}
    return tuple(sorted((f for f in flows if f is not None),
                        key=lambda f: (f.resource_id, f.topic, f.source.broker)))
