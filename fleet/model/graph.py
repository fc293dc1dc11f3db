"""A vehicle's description as triples: the Turtle document plug and play writes for one AGV.

What one vehicle becomes (``<base>`` is the plant's :class:`~fleet.model.binding.FleetBinding`
base IRI, ``<id>`` the vehicle id of :func:`agv_id`):

- ``<base>agv-<id>``: a ``pk:Resource`` with ``pk:isType fleet:agv``, ``pk:name``, ``pk:brand``
  (the manufacturer), ``fleet:interface`` / ``manufacturer`` / ``serialNumber`` /
  ``connectionState`` / ``pinned`` and ``fleet:discovered true``; it ``pk:sendsTo`` the binding's
  MQTT broker, publishes and subscribes its channels, ``pk:executes`` its skills and
  ``pk:hasProperty`` its properties;
- one ``pk:Topic`` per channel (``<base>agv-<id>-<channel>``), carried (``pk:hasTopic``) by the
  MQTT broker, with the interface's QoS and retain, ``fleet:channel``, and for the channels the
  fleet view reads (VDA 5050 state, connection, factsheet; paper status, movement, description)
  ``pk:entityId "urn:ngsi-ld:AGV:<serial>"`` and ``pk:entityType "AGV"``: one NGSI entity per
  vehicle whose attributes the bridge merges from those topics;
- one ``pk:Skill`` per skill (``<base><skill>``, ``pk:id`` = ``pk:name`` = the skill: vehicles
  with the same skill share the individual, the triples are the same) and one ``pk:Property``
  per property (``<base>agv-<id>-<property id>``, an ``xsd:decimal`` value).

The context broker is not written here: the fleet module's rules make every ``fleet:fleet-view``
subscribe to (and publish) the channels, and the core rules derive the topics the context broker
must carry and the bridge. The vehicle id is the serial number, except that ``:`` (allowed in a
serial, not in a ``pk:id``) becomes ``_`` and the id gets ``-`` and 8 hex digits of the serial's
SHA-1, so two serials never share an id.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

from rdflib import Graph, Literal, Namespace, URIRef
from rdflib.namespace import OWL, RDF, XSD

from fleet.model.binding import FleetBinding
from fleet.model.description import AgvDescription, check
from fleet.model.errors import DescriptionError
from fleet.vda5050 import topics as vda_topics
from kg.namespaces import FLEET, PK

CONNECTION_STATES = ("ONLINE", "OFFLINE", "CONNECTIONBROKEN")
ENTITY_TYPE = "AGV"


@dataclass(frozen=True)
class Channel:
    """One channel of an interface: its name, who publishes it, its MQTT QoS and retain flag, and
    whether it is part of the vehicle's NGSI entity (bridged to the context broker)."""

    name: str
    vehicle_publishes: bool
    qos: int
    retain: bool
    entity: bool


def _vda(name: str, entity: bool) -> Channel:
    rule = vda_topics.rule(name)
    return Channel(name, not vda_topics.Subtopic(name).from_master, rule.qos, rule.retain, entity)


#: The channels of each interface (VDA 5050 2.1 section 6.5; the paper's section 4.3, with the
#: QoS and retain fleet/paper uses: status and description retained, commands QoS 1).
CHANNELS: dict[str, tuple[Channel, ...]] = {
    "vda5050": (
        _vda("order", False), _vda("instantActions", False), _vda("state", True),
        _vda("visualization", False), _vda("connection", True), _vda("factsheet", True),
    ),
    "paper-channels": (
        Channel("action_channel", False, 1, False, False),
        Channel("motion_channel", False, 1, False, False),
        Channel("movement_channel", True, 0, False, True),
        Channel("status_channel", True, 1, True, True),
        Channel("description_channel", True, 1, True, True),
    ),
}


def agv_id(serial: str) -> str:
    """The vehicle's id part: the serial, or with ``:`` replaced and a hash added (module docstring)."""
    if ":" not in serial:
        return serial
    return serial.replace(":", "_") + "-" + hashlib.sha1(serial.encode()).hexdigest()[:8]


def entity_id(serial: str) -> str:
    """The vehicle's NGSI entity on the context broker."""
    return f"urn:ngsi-ld:{ENTITY_TYPE}:{serial}"


def topic_name(desc: AgvDescription, channel: str) -> str:
    """The MQTT topic of one of the vehicle's channels."""
    if desc.interface == "vda5050":
        return vda_topics.topic(desc.manufacturer, desc.serial, channel)
    return f"{desc.serial}/{channel}"


def agv_iri(desc: AgvDescription, binding: FleetBinding) -> str:
    """The IRI the vehicle has in the plant."""
    return f"{binding.base_iri}agv-{agv_id(check(desc).serial)}"


def agv_graph(desc: AgvDescription, binding: FleetBinding, *, connection_state: str = "ONLINE",
              pinned: bool = False, secret_ref: str | None = None, discovered: bool = True) -> Graph:
    """The vehicle's triples (see the module docstring); checks everything first.

    ``secret_ref``: the vehicle's ``pk:secretRef`` (where its password is), for a vehicle a person
    admitted to a closed broker (``plantkg fleet admit``); ``discovered`` false: admitted, its
    description not heard yet (``fleet:discovered false``, no skills or properties)."""
    check(desc)
    if secret_ref is not None and not (isinstance(secret_ref, str) and secret_ref.startswith(("file:", "env:"))):
        raise DescriptionError("secret_ref", secret_ref, "must be a file: or env: reference")
    if not isinstance(discovered, bool):
        raise DescriptionError("discovered", discovered, "must be true or false")
    if not isinstance(binding, FleetBinding):
        raise DescriptionError("binding", binding, "must be a FleetBinding (fleet.model.binding.fleet_binding)")
    if connection_state not in CONNECTION_STATES:
        raise DescriptionError("connection_state", connection_state, f"must be one of {', '.join(CONNECTION_STATES)}")
    if not isinstance(pinned, bool):
        raise DescriptionError("pinned", pinned, "must be true or false")
    base = Namespace(binding.base_iri)
    local = f"agv-{agv_id(desc.serial)}"
    agv, mqtt = base[local], URIRef(binding.mqtt_broker_iri)
    g = Graph()
    g.bind("pk", PK)
    g.bind("fleet", FLEET)
    g.bind("xsd", XSD)
    g.bind("owl", OWL)
    g.bind("plant", base)

    def individual(node: URIRef, cls: URIRef, ident: str, name: str) -> None:
        g.add((node, RDF.type, OWL.NamedIndividual))
        g.add((node, RDF.type, cls))
        g.add((node, PK.id, Literal(ident)))
        g.add((node, PK.name, Literal(name)))

    individual(agv, PK.Resource, local, desc.name)
    for p, o in ((PK.brand, Literal(desc.manufacturer)), (PK.isType, FLEET.agv), (PK.sendsTo, mqtt),
                 (FLEET.interface, Literal(desc.interface)), (FLEET.manufacturer, Literal(desc.manufacturer)),
                 (FLEET.serialNumber, Literal(desc.serial)), (FLEET.discovered, Literal(discovered)),
                 (FLEET.connectionState, Literal(connection_state)), (FLEET.pinned, Literal(pinned))):
        g.add((agv, p, o))
    if secret_ref is not None:
        g.add((agv, PK.secretRef, Literal(secret_ref)))
    for channel in CHANNELS[desc.interface]:
        topic = base[f"{local}-{channel.name}"]
        individual(topic, PK.Topic, f"{local}-{channel.name}", topic_name(desc, channel.name))
        g.add((topic, FLEET.channel, Literal(channel.name)))
        g.add((topic, PK.valueTopic, Literal(channel.name)))
        g.add((topic, PK.typeTopic, Literal("json")))
        g.add((topic, PK.qos, Literal(channel.qos)))
        g.add((topic, PK.retain, Literal(channel.retain)))
        if channel.entity:
            g.add((topic, PK.entityId, Literal(entity_id(desc.serial))))
            g.add((topic, PK.entityType, Literal(ENTITY_TYPE)))
        g.add((mqtt, PK.hasTopic, topic))
        g.add((agv, PK.publishes if channel.vehicle_publishes else PK.subscribes, topic))
    for skill in desc.skills:
        node = base[skill]
        individual(node, PK.Skill, skill, skill)
        g.add((agv, PK.executes, node))
    for prop in desc.properties:
        node = base[f"{local}-{prop.id}"]
        individual(node, PK.Property, f"{local}-{prop.id}", prop.name)
        g.add((node, PK.value, Literal(prop.value, datatype=XSD[prop.value_type])))
        g.add((node, PK.valueType, Literal(prop.value_type)))
        g.add((agv, PK.hasProperty, node))
    return g


def agv_turtle(desc: AgvDescription, binding: FleetBinding, *, connection_state: str = "ONLINE",
               pinned: bool = False, secret_ref: str | None = None, discovered: bool = True) -> str:
    """The vehicle's triples as a whole Turtle document (prefixes included)."""
    graph = agv_graph(desc, binding, connection_state=connection_state, pinned=pinned,
                      secret_ref=secret_ref, discovered=discovered)
    header = (f"# AGV {desc.serial} ({desc.interface}, {desc.manufacturer}), written by fleet.model.graph.\n")
    return header + graph.serialize(format="turtle")
