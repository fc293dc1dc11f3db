"""Where a plant's fleet lives: the MQTT broker the vehicles send to, the context broker the fleet
view reads, and the IRI base discovered vehicles are named under. Found by SPARQL over the plant.

- ``mqtt_broker_iri``: the Mosquitto broker (``pk:brokerType "mosquitto"``) a resource of type
  ``fleet:fleet-manager`` sends to. Exactly one such broker: none, or fleet managers on two
  different Mosquitto brokers, is a :class:`~fleet.model.errors.BindingError`.
- ``context_broker_iri``: the context broker (``"ngsi-v2"``) a ``fleet:fleet-view`` resource sends
  to; ``None`` when the plant has no fleet view there; two different ones are an error.
- ``base_iri``: the namespace of the fleet manager's IRI (up to its last ``#`` or ``/``), so a
  vehicle found by plug and play gets the IRI a person would give it in the same plant file.

Only asserted facts are read (no reasoning): the binding is asked before a vehicle is added.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import pyoxigraph as ox

from fleet.model.errors import BindingError
from kg.load import PlantGraph, load_plant
from kg.namespaces import FLEET, PK

_PREFIXES = {"pk": str(PK), "fleet": str(FLEET)}

MANAGERS = """
SELECT DISTINCT ?manager ?broker WHERE {
    ?manager pk:isType fleet:fleet-manager ; pk:sendsTo ?broker .
    ?broker pk:brokerType ?kind .
    FILTER (STR(?kind) = "mosquitto")
} ORDER BY ?manager ?broker"""

VIEWS = """
SELECT DISTINCT ?view ?broker WHERE {
    ?view pk:isType fleet:fleet-view ; pk:sendsTo ?broker .
    ?broker pk:brokerType ?kind .
    FILTER (STR(?kind) = "ngsi-v2")
} ORDER BY ?view ?broker"""


@dataclass(frozen=True)
class FleetBinding:
    """The plant's fleet brokers and the base of discovered vehicles' IRIs (module docstring)."""

    mqtt_broker_iri: str
    context_broker_iri: str | None
    base_iri: str

    def __post_init__(self) -> None:
        for name in ("mqtt_broker_iri", "base_iri"):
            if not isinstance(getattr(self, name), str) or not getattr(self, name):
                raise BindingError(f"{name} must be a non-empty IRI string, is {getattr(self, name)!r}")
        if self.context_broker_iri is not None and not isinstance(self.context_broker_iri, str):
            raise BindingError(f"context_broker_iri must be an IRI string or None, is {self.context_broker_iri!r}")
        if not self.base_iri.endswith(("#", "/")):
            raise BindingError(f"base_iri {self.base_iri!r} must end with # or /")
        for name in ("mqtt_broker_iri", "context_broker_iri", "base_iri"):
            value = getattr(self, name)
            if value is not None:
                try:
                    ox.NamedNode(value)
                except ValueError as exc:
                    raise BindingError(f"{name} {value!r} is not an IRI: {exc}") from None


def fleet_binding(plant_files: Iterable[Path | str]) -> FleetBinding:
    """The binding of the plant in ``plant_files`` (kg.load errors for unusable files)."""
    return binding_of(load_plant(list(plant_files)))


def binding_of(plant: PlantGraph) -> FleetBinding:
    """The binding of an already loaded plant."""
    def rows(query: str) -> list[tuple[str, str]]:
        answer = plant.store.query(query, prefixes=_PREFIXES, use_default_graph_as_union=True)
        return [(r[0].value, r[1].value) for r in answer]  # type: ignore[index, union-attr]

    managers = rows(MANAGERS)
    if not managers:
        raise BindingError("the plant has no fleet manager on a Mosquitto broker (a pk:Resource with "
                           "pk:isType fleet:fleet-manager that pk:sendsTo a broker of pk:brokerType "
                           "\"mosquitto\"), so there is no MQTT broker to put vehicles on")
    brokers = sorted({b for _, b in managers})
    if len(brokers) > 1:
        raise BindingError(f"fleet managers send to several Mosquitto brokers ({', '.join(brokers)}); "
                           "plug and play needs the one broker the vehicles send to",
                           hint="let every fleet:fleet-manager resource send to the same Mosquitto broker")
    contexts = sorted({b for _, b in rows(VIEWS)})
    if len(contexts) > 1:
        raise BindingError(f"fleet views send to several context brokers ({', '.join(contexts)}); "
                           "the fleet's NGSI entities need one",
                           hint="let every fleet:fleet-view resource send to the same context broker")
    manager = managers[0][0]
    cut = max(manager.rfind("#"), manager.rfind("/"))
    if cut < 0:
        raise BindingError(f"the fleet manager's IRI {manager!r} has no namespace (no # or /) to name "
                           "discovered vehicles under", hint="give the fleet manager an http(s) IRI")
    return FleetBinding(mqtt_broker_iri=brokers[0], context_broker_iri=contexts[0] if contexts else None,
                        base_iri=manager[: cut + 1])
