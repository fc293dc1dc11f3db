"""Which plant a plant is: the owner name recorded with everything it deploys (docs/operating.md).

Agents record an owner with each broker, topic and bridge, and a plant plans, applies and destroys
only what it owns (engine.plan). The owner of a plant is, in this order:

1. the name it declares with ``pk:plantName`` on its ``owl:Ontology`` header (one name; a short
   stable name such as ``"line-3"`` survives a change of the ontology IRI);
2. else its ``owl:Ontology`` IRI (the plant files' own, not plantkg's);
3. else None: the plant owns what nobody owns, as before ownership existed.

Two different names, or two ontology IRIs and no name, are ambiguous: :class:`OwnerError` asks
for a ``pk:plantName`` (or the caller's explicit owner, e.g. ``--owner``).
"""

from __future__ import annotations

import pyoxigraph as ox

from engine.errors import EngineError
from kg.load import PlantGraph
from kg.namespaces import ONTOLOGY_IRI, OWL, PK, RDF

MAX_OWNER = 512


class OwnerError(EngineError):
    """The plant's owner cannot be told (ambiguous, or not a usable name)."""


def check_owner_name(owner: str, where: str = "owner") -> str:
    """``owner`` if usable as an owner (1 to 512 printable characters, no whitespace), else
    :class:`OwnerError` naming ``where``."""
    if not 1 <= len(owner) <= MAX_OWNER or not owner.isprintable() or any(c.isspace() for c in owner):
        raise OwnerError(f"{where} {owner!r} is not a usable owner name",
                         hint=f"use 1 to {MAX_OWNER} printable characters without whitespace, "
                              "e.g. the plant's ontology IRI or a name such as line-3")
    return owner


def plant_owner(plant: PlantGraph) -> str | None:
    """The owner of ``plant`` (see the module docstring)."""
    names: set[str] = set()
    ontologies: set[str] = set()
    name_prop, onto_type = ox.NamedNode(str(PK.plantName)), ox.NamedNode(str(OWL.Ontology))
    a = ox.NamedNode(str(RDF.type))
    for graph in plant.plant_graphs:
        for quad in plant.store.quads_for_pattern(None, name_prop, None, graph):
            if isinstance(quad.object, ox.Literal):
                names.add(quad.object.value)
        for quad in plant.store.quads_for_pattern(None, a, onto_type, graph):
            if isinstance(quad.subject, ox.NamedNode) and not quad.subject.value.startswith(ONTOLOGY_IRI):
                ontologies.add(quad.subject.value)
    if len(names) > 1:
        raise OwnerError(f"the plant declares {len(names)} names with pk:plantName: "
                         + ", ".join(sorted(names)), hint="keep one pk:plantName")
    if names:
        return check_owner_name(names.pop(), "pk:plantName")
    if len(ontologies) > 1:
        raise OwnerError("the plant files declare several ontologies (" + ", ".join(sorted(ontologies))
                         + "), so which plant owns what they deploy is ambiguous",
                         hint='declare the owner on one header: pk:plantName "my-plant"; or give '
                              "it with --owner")
    return check_owner_name(ontologies.pop(), "owl:Ontology IRI") if ontologies else None
