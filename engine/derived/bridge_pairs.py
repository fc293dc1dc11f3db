"""From directed bridge facts to one :class:`~engine.model.BridgeSpec` per pair of brokers (pure).

The ontology says ``requiresBridge(a, c)`` per direction (asserted ``pk:bridgesTo`` or derived by
rule R1), forwarding the topics derive found for that direction. What runs is one bridge per *pair*, because
both directions of a pair must share one connection or messages loop: two Mosquitto bridges
A -> C and C -> A on the same topic would hand each message back and forth forever, while one
``connection`` with ``topic t both`` is loop-free (Mosquitto does not echo a bridge's own
messages); a worker bridging MQTT and Kafka both ways skips what it wrote itself.

- Mechanism, from the brokers' inferred classes (the ontology decides what a broker is):
  two ``pk:MqttBroker`` -> Mosquitto's own bridge, carried by a Mosquitto (an MQTT broker of
  another type, a plugin's class declared a subclass of ``pk:MqttBroker``, is only ever its far
  end: reached at its ``pk:mqttPort``, one way only, since without Mosquitto's bridge flag it
  would send back what the bridge wrote; two such brokers are refused, and so is such a broker
  with a Kafka or a context broker); an MQTT and a ``pk:KafkaBroker`` -> a bridge
  worker; an MQTT and a ``pk:ContextBroker`` -> an MQTT <-> NGSI worker; two Kafka brokers (or
  clusters) -> a MirrorMaker 2, one way only, carried by the target. A context broker bridges to
  MQTT only (Kafka or another context broker: route the topic through an MQTT broker): refused,
  with what to do.
- Carrier (``local``): a worker runs beside the MQTT broker; a one-way Mosquitto bridge is carried
  by its source (it pushes); a two-way one by the broker with the smaller id — unless that would
  make it connect to an IPv6 address, which Mosquitto's bridge cannot (its ``address`` line takes
  no IPv6 literal): then by the other, and if both are IPv6 (or a one-way bridge's target is) the
  bridge is refused here, before anything is deployed. An ``external`` broker (``pk:external``,
  not deployed by plantkg) never carries a bridge: its agent does not exist.
- Each shared topic is a :class:`BridgeRoute` with its direction seen from the carrier, the topic's
  ``pk:qos`` (default 1: at-least-once) and, for a worker, its ``pk:kafkaKey``; for an NGSI worker
  the entity the topic is on the context broker (id and type, defaults applied by derive).
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

from engine.errors import EngineError
from engine.model import (
    BridgeDirection,
    BridgeEnd,
    BridgeMechanism,
    BridgeRoute,
    BridgeSpec,
    BrokerSpec,
)
from engine.security import kafka_client

#: The inferred broker classes a bridge mechanism is chosen from (as engine.reasoning.rules_fast.short_name writes them).
MQTT_CLASS = "pk:MqttBroker"
KAFKA_CLASS = "pk:KafkaBroker"
NGSI_CLASS = "pk:ContextBroker"
#: The driver whose own bridge the MOSQUITTO mechanism is: only such a broker carries one.
MOSQUITTO_KIND = "mosquitto"
DEFAULT_QOS = 1
DEFAULT_KEY = "mqtt-topic"


class BridgeNotSupportedError(EngineError):
    """A bridge between two brokers of classes plantkg cannot bridge (two Kafka brokers both ways, a
    context broker and anything but MQTT, an external broker that would have to carry it)."""

    def __init__(self, a: str, c: str, why: str, hint: str | None = None) -> None:
        super().__init__(f"bridge {a} -> {c}: {why}",
                         hint=hint or "remove the pk:bridgesTo, or route the topic through an MQTT "
                                      "broker (for a bridge the rules derive: move the publisher or "
                                      "subscriber)")


@dataclass(frozen=True)
class DirectedBridge:
    """``requiresBridge(source, target)`` with the topic names it forwards that way."""

    source: str
    target: str
    topics: frozenset[str]
    asserted: bool


@dataclass(frozen=True)
class TopicOptions:
    """What a bridge needs of a topic: its MQTT QoS and Kafka key mode, if the plant sets them, and
    the NGSI entity it is on a context broker (derive applies the entity defaults)."""

    qos: int | None = None
    kafka_key: str | None = None
    entity_id: str | None = None
    entity_type: str | None = None


def pair_bridges(
    directed: Iterable[DirectedBridge],
    brokers: Mapping[str, BrokerSpec],
    classes: Mapping[str, frozenset[str]],
    options: Mapping[str, TopicOptions],
    external: frozenset[str] = frozenset(),
) -> list[BridgeSpec]:
    """One BridgeSpec per unordered broker pair, sorted by address; ``external`` brokers (ids)
    are not deployed by plantkg, so they never carry one."""
    pairs: dict[frozenset[str], list[DirectedBridge]] = defaultdict(list)
    for bridge in directed:
        pairs[frozenset((bridge.source, bridge.target))].append(bridge)
    specs = [_pair(sorted(ds, key=lambda d: d.source), brokers, classes, options, external)
             for ds in pairs.values()]
    return sorted(specs, key=lambda s: s.address)


def _pair(ds: list[DirectedBridge], brokers: Mapping[str, BrokerSpec],
          classes: Mapping[str, frozenset[str]], options: Mapping[str, TopicOptions],
          external: frozenset[str]) -> BridgeSpec:
    first = ds[0]
    mechanism, local = _mechanism_and_carrier(first.source, first.target, ds, classes, brokers, external)
    remote = first.target if local == first.source else first.source
    out = set().union(*(d.topics for d in ds if d.source == local))
    into = set().union(*(d.topics for d in ds if d.source == remote))
    routes = []
    for topic in sorted(out | into):
        direction = (BridgeDirection.BOTH if topic in out and topic in into
                     else BridgeDirection.OUT if topic in out else BridgeDirection.IN)
        opts = options.get(topic, TopicOptions())
        key = (opts.kafka_key or DEFAULT_KEY) if mechanism is BridgeMechanism.WORKER else DEFAULT_KEY
        qos = DEFAULT_QOS if opts.qos is None else opts.qos
        ngsi = mechanism is BridgeMechanism.NGSI
        routes.append(BridgeRoute(topic, direction, qos, key,
                                  entity_id=opts.entity_id if ngsi else None,
                                  entity_type=opts.entity_type if ngsi else None))
    return BridgeSpec(local=bridge_end(brokers[local], classes), remote=bridge_end(brokers[remote], classes), mechanism=mechanism,
                      routes=tuple(routes), asserted=any(d.asserted for d in ds))


def _mechanism_and_carrier(a: str, c: str, ds: list[DirectedBridge], classes: Mapping[str, frozenset[str]],
                           brokers: Mapping[str, BrokerSpec],
                           external: frozenset[str]) -> tuple[BridgeMechanism, str]:
    mqtt = {b for b in (a, c) if MQTT_CLASS in classes.get(b, frozenset())}
    kafka = {b for b in (a, c) if KAFKA_CLASS in classes.get(b, frozenset())}
    ngsi = {b for b in (a, c) if NGSI_CLASS in classes.get(b, frozenset())}
    if len(mqtt) == 2:
        others = [b for b in (a, c) if brokers[b].kind != MOSQUITTO_KIND]
        if others:
            return BridgeMechanism.MOSQUITTO, _foreign_mqtt_carrier(a, c, ds, brokers, external, others)
        sources = sorted({d.source for d in ds})
        deployed = [s for s in sources if s not in external]
        if not deployed:
            raise _external_carrier(a, c, sources[0])
        carriers = [s for s in deployed if not _ipv6(brokers[c if s == a else a].host)]
        if not carriers:
            target = c if sources[0] == a else a
            raise BridgeNotSupportedError(a, c, f"Mosquitto's bridge cannot connect to broker "
                                          f"{target!r} at the IPv6 address {brokers[target].host} "
                                          "(its 'address' takes no IPv6 literal); give it an IPv4 "
                                          "address")
        return BridgeMechanism.MOSQUITTO, carriers[0]
    if len(mqtt) == 1 and (len(kafka) == 1 or len(ngsi) == 1):
        carrier = next(iter(mqtt))
        if brokers[carrier].kind != MOSQUITTO_KIND:
            raise BridgeNotSupportedError(
                a, c, f"the bridge worker runs beside a Mosquitto; {carrier!r} is a "
                      f"{brokers[carrier].kind!r} broker",
                hint="route the topic through a Mosquitto broker, bridged one way to "
                     f"{carrier!r}, or remove the pk:bridgesTo")
        if carrier in external:
            raise _external_carrier(a, c, carrier)
        return (BridgeMechanism.WORKER if kafka else BridgeMechanism.NGSI), carrier
    if len(kafka) == 2:
        return BridgeMechanism.MIRROR, _mirror_carrier(a, c, ds, external)
    if ngsi and (kafka or len(ngsi) == 2):
        other = "a Kafka broker" if kafka else "another context broker"
        raise BridgeNotSupportedError(
            a, c, f"a context broker bridges to an MQTT broker only, not to {other}",
            hint="route the topic through an MQTT broker: the publisher and the subscriber each "
                 "send to (or bridge with) a Mosquitto broker, which bridges to the context broker "
                 "and to the other broker; or remove the pk:bridgesTo")
    raise BridgeNotSupportedError(a, c, "plantkg bridges an MQTT broker to an MQTT, a Kafka or a "
                                  "context broker; these brokers are not both of such classes")


def _foreign_mqtt_carrier(a: str, c: str, ds: list[DirectedBridge], brokers: Mapping[str, BrokerSpec],
                          external: frozenset[str], others: list[str]) -> str:
    """The Mosquitto that carries a bridge to an MQTT broker of another type (``others``): it
    pushes to it (one way out) or pulls from it (one way in), never both."""
    if len(others) == 2:
        raise BridgeNotSupportedError(
            a, c, f"neither broker is a Mosquitto (types {brokers[a].kind!r} and {brokers[c].kind!r}), "
                  "and only Mosquitto's own bridge joins two MQTT brokers",
            hint="put a Mosquitto broker between them, bridged one way to each, or remove the pk:bridgesTo")
    carrier = c if others[0] == a else a
    if len({d.source for d in ds}) == 2:
        raise BridgeNotSupportedError(
            a, c, f"a two-way bridge needs Mosquitto's bridge flag (try_private) on both ends, and "
                  f"{others[0]!r} is a {brokers[others[0]].kind!r} broker: it would send every "
                  "message the bridge wrote back to it",
            hint="bridge one way only: keep the pk:bridgesTo (or the publisher/subscriber) of one "
                 "direction, and route the other through another Mosquitto")
    if carrier in external:
        raise _external_carrier(a, c, carrier)
    if _ipv6(brokers[others[0]].host):
        raise BridgeNotSupportedError(a, c, f"Mosquitto's bridge cannot connect to broker "
                                      f"{others[0]!r} at the IPv6 address {brokers[others[0]].host} "
                                      "(its 'address' takes no IPv6 literal); give it an IPv4 address")
    return carrier


def _mirror_carrier(a: str, c: str, ds: list[DirectedBridge], external: frozenset[str]) -> str:
    """The Kafka that runs a MirrorMaker 2 between two Kafka brokers (or clusters): the target,
    which pulls from the source (MirrorMaker 2's advice: consume remotely, produce locally). One
    way only: with topic names kept (IdentityReplicationPolicy) a mirror both ways would copy every
    record back for ever."""
    sources = sorted({d.source for d in ds})
    if len(sources) == 2:
        raise BridgeNotSupportedError(
            a, c, "MirrorMaker 2 bridges two Kafka brokers one way only: it keeps the topic names, "
                  "so a mirror both ways would copy each record back and forth for ever",
            hint="keep one direction (the publisher on one Kafka, the subscribers on the other), "
                 "or give the other direction's topics other names")
    target = c if sources[0] == a else a
    if target in external:
        raise _external_carrier(a, c, target)
    return target


def _external_carrier(a: str, c: str, carrier: str) -> BridgeNotSupportedError:
    return BridgeNotSupportedError(
        a, c, f"the bridge would run beside broker {carrier!r}, which is pk:external (plantkg does "
              "not deploy it, so no agent of plantkg can carry the bridge)",
        hint=f"let a broker plantkg deploys carry it: drop pk:external from {carrier!r}, or put "
             "a deployed MQTT broker between the two")


def _ipv6(host: str) -> bool:
    return ":" in host


def bridge_end(spec: BrokerSpec, classes: Mapping[str, frozenset[str]]) -> BridgeEnd:
    """Where a bridge reaches ``spec``: an MQTT broker at its ``pk:mqttPort`` if it has one (its
    ``pk:port`` speaks another protocol), every other broker at its ``pk:port``; ``closed`` when
    it is a Kafka closed to anonymous clients (a worker or a MirrorMaker 2 logs in there as
    plantkg's principal)."""
    mqtt = MQTT_CLASS in classes.get(spec.id, frozenset()) and spec.mqtt_port is not None
    return BridgeEnd(id=spec.id, kind=spec.kind, host=spec.host,
                     port=spec.mqtt_port if mqtt else spec.port,  # type: ignore[arg-type]
                     tls=spec.tls, closed=kafka_client.is_closed(spec),
                     bootstrap=spec.kafka.bootstrap if spec.kafka is not None else ())
