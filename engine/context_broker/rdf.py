"""The NGSI <-> RDF mapping: an entity as quads in its tenant's named graph, and back.

One named graph per tenant: ``<NGSI_GRAPH_BASE><service or _><service path>``, e.g.
``https://w3id.org/plantkg/graph/ngsi/_/`` (default service, path ``/``) or
``.../ngsi/plant/hall1``. In it, an entity (id ``E``, type ``T``) is::

    <node> a <type IRI> ; ngsi:entityId "E" ; ngsi:entityType "T" ;
           ngsi:dateCreated "..."^^xsd:dateTime ; ngsi:dateModified "..."^^xsd:dateTime ;
           ngsi:hasAttribute <attr> .
    <attr> a ngsi:Attribute ; ngsi:name "temperature" ; ngsi:attributeType "Number" ;
           ngsi:hasValue 21.5 ; ngsi:dateCreated ... ; ngsi:dateModified ... ;
           ngsi:hasMetadata <attr>/metadata/accuracy .
    <attr>/metadata/accuracy a ngsi:Metadata ; ngsi:name "accuracy" ;
           ngsi:metadataType "Number" ; ngsi:hasValue 0.5 .

- ``<node>`` is the id itself when it is an absolute IRI (``urn:ngsi-ld:AGV:1``) and no other
  entity of the tenant holds that IRI already (same id, another type); else the minted
  ``NGSI_ENTITY_BASE<T>/<E>`` (percent-encoded). The node is remembered with the entity.
- ``<type IRI>``: ``T`` when it is an absolute IRI, else ``NGSI_TYPE_BASE<T>``.
- ``<attr>``: ``NGSI_ENTITY_BASE<T>/<E>/attrs/<name>``, whatever the node.
- Values by their JSON kind: a string is ``xsd:string`` (``xsd:dateTime`` when the NGSI type is
  DateTime/ISO8601), an integer ``xsd:integer``, any other number ``xsd:double``, a boolean
  ``xsd:boolean``; objects, arrays and null are ``rdf:JSON``. The NGSI type travels apart
  (``ngsi:attributeType``), so every value comes back exactly as it was written.

Pure: quads are rendered as N-Triples terms (what SPARQL Update ``DATA`` blocks take), and read
back from pyoxigraph terms. No I/O here; :mod:`.store` writes and reads them.
"""

from __future__ import annotations

import json
import re
from collections import defaultdict
from functools import lru_cache
from collections.abc import Iterable
from datetime import datetime, timezone
from typing import Any
from urllib.parse import quote

import pyoxigraph as ox

from engine.context_broker.contract import Tenant
from engine.context_broker.dates import parse_datetime, render_datetime
from engine.context_broker.entities import DATE_TYPES, Attribute, Entity
from kg.namespaces import NGSI, NGSI_ENTITY_BASE, NGSI_GRAPH_BASE, NGSI_TYPE_BASE, RDF, RDF_JSON, XSD

_ABSOLUTE_IRI = re.compile(r"[A-Za-z][A-Za-z0-9+.-]*:[^\s<>\"{}|\\^`]+\Z")
Triple = tuple[str, str, str]


def _nt(iri: str) -> str:
    return str(ox.NamedNode(iri))


P_TYPE = _nt(str(RDF.type))
P_ID, P_ETYPE = _nt(str(NGSI.entityId)), _nt(str(NGSI.entityType))
P_CREATED, P_MODIFIED = _nt(str(NGSI.dateCreated)), _nt(str(NGSI.dateModified))
P_HAS_ATTR, P_NAME = _nt(str(NGSI.hasAttribute)), _nt(str(NGSI.name))
P_ATYPE, P_MTYPE = _nt(str(NGSI.attributeType)), _nt(str(NGSI.metadataType))
P_VALUE, P_HAS_MD = _nt(str(NGSI.hasValue)), _nt(str(NGSI.hasMetadata))
C_ATTRIBUTE, C_METADATA = _nt(str(NGSI.Attribute)), _nt(str(NGSI.Metadata))
XSD_STRING, XSD_INTEGER, XSD_DOUBLE = str(XSD.string), str(XSD.integer), str(XSD.double)
XSD_BOOLEAN, XSD_DATETIME = str(XSD.boolean), str(XSD.dateTime)


@lru_cache(maxsize=4096)
def is_absolute_iri(text: str) -> bool:
    """An absolute IRI Oxigraph accepts as it is (checked once per distinct text)."""
    if not _ABSOLUTE_IRI.match(text):
        return False
    try:
        ox.NamedNode(text)
    except ValueError:
        return False
    return True


def graph_iri(tenant: Tenant) -> str:
    return f"{NGSI_GRAPH_BASE}{tenant.service or '_'}{tenant.service_path}"


def tenant_of_graph(iri: str) -> Tenant | None:
    if not iri.startswith(NGSI_GRAPH_BASE):
        return None
    service, slash, path = iri[len(NGSI_GRAPH_BASE):].partition("/")
    if not slash:
        return None
    return Tenant("" if service == "_" else service, "/" + path)


@lru_cache(maxsize=65536)
def minted_node(entity_id: str, entity_type: str) -> str:
    return f"{NGSI_ENTITY_BASE}{quote(entity_type, safe='')}/{quote(entity_id, safe='')}"


def preferred_node(entity_id: str, entity_type: str) -> str:
    return entity_id if is_absolute_iri(entity_id) else minted_node(entity_id, entity_type)


@lru_cache(maxsize=4096)
def type_iri(entity_type: str) -> str:
    return entity_type if is_absolute_iri(entity_type) else NGSI_TYPE_BASE + quote(entity_type, safe="")


@lru_cache(maxsize=65536)
def attr_iri(entity_id: str, entity_type: str, name: str) -> str:
    return f"{minted_node(entity_id, entity_type)}/attrs/{quote(name, safe='')}"


_ESCAPES = {c: f"\\u{c:04X}" for c in (*range(0x20), 0x7F)}
_ESCAPES.update({0x08: "\\b", 0x09: "\\t", 0x0A: "\\n", 0x0C: "\\f", 0x0D: "\\r",
                 0x22: '\\"', 0x5C: "\\\\"})


def _literal(text: str, datatype: str) -> str:
    """N-Triples (and SPARQL) literal, escaped exactly as pyoxigraph serializes it (unit
    tested) without building its objects on every write."""
    escaped = text.translate(_ESCAPES)
    return f'"{escaped}"' if datatype == XSD_STRING else f'"{escaped}"^^<{datatype}>'


def _stamp(seconds: float) -> str:
    return _literal(datetime.fromtimestamp(seconds, timezone.utc).isoformat().replace("+00:00", "Z"),
                    XSD_DATETIME)


def value_literal(value: Any, ngsi_type: str) -> str:
    """The N-Triples literal of an attribute or metadata value."""
    if isinstance(value, bool):
        return _literal("true" if value else "false", XSD_BOOLEAN)
    if isinstance(value, int):
        return _literal(str(value), XSD_INTEGER)
    if isinstance(value, float):
        return _literal(repr(value), XSD_DOUBLE)
    if isinstance(value, str):
        return _literal(value, XSD_DATETIME if ngsi_type in DATE_TYPES else XSD_STRING)
    return _literal(json.dumps(value, ensure_ascii=False, separators=(",", ":")), RDF_JSON)


def head_triples(entity: Entity, node: str) -> frozenset[Triple]:
    """The entity's own triples (type, id, type name, dates, links to its attributes)."""
    s = f"<{node}>"
    out = [(s, P_TYPE, f"<{type_iri(entity.type)}>"), (s, P_ID, _literal(entity.id, XSD_STRING)),
           (s, P_ETYPE, _literal(entity.type, XSD_STRING)), (s, P_CREATED, _stamp(entity.created)),
           (s, P_MODIFIED, _stamp(entity.modified))]
    out += [(s, P_HAS_ATTR, f"<{attr_iri(entity.id, entity.type, name)}>") for name in entity.attrs]
    return frozenset(out)


def attribute_triples(entity_id: str, entity_type: str, name: str, attr: Attribute) -> frozenset[Triple]:
    """The triples of one attribute node and its metadata nodes."""
    a_iri = attr_iri(entity_id, entity_type, name)
    a = f"<{a_iri}>"
    out = [(a, P_TYPE, C_ATTRIBUTE), (a, P_NAME, _literal(name, XSD_STRING)),
           (a, P_ATYPE, _literal(attr.type, XSD_STRING)), (a, P_VALUE, value_literal(attr.value, attr.type)),
           (a, P_CREATED, _stamp(attr.created)), (a, P_MODIFIED, _stamp(attr.modified))]
    for md_name, md in attr.metadata.items():
        m = f"<{a_iri}/metadata/{quote(md_name, safe='')}>"
        out += [(a, P_HAS_MD, m), (m, P_TYPE, C_METADATA), (m, P_NAME, _literal(md_name, XSD_STRING)),
                (m, P_MTYPE, _literal(str(md["type"]), XSD_STRING)),
                (m, P_VALUE, value_literal(md["value"], str(md["type"])))]
    return frozenset(out)


def entity_triples(entity: Entity, node: str) -> frozenset[Triple]:
    """All triples of ``entity`` (in N-Triples terms) with ``node`` as its subject."""
    out = set(head_triples(entity, node))
    for name, attr in entity.attrs.items():
        out |= attribute_triples(entity.id, entity.type, name, attr)
    return frozenset(out)


def update_text(graph: str, delete: Iterable[Triple], insert: Iterable[Triple]) -> str | None:
    """One SPARQL Update (one transaction) deleting then inserting the given triples in ``graph``.
    Every term is a pyoxigraph term's own N-Triples serialization: no request text is spliced
    into the update's syntax."""
    g = _nt(graph)
    parts = []
    delete, insert = list(delete), list(insert)
    if delete:
        parts.append(f"DELETE DATA {{ GRAPH {g} {{ " + " ".join(f"{s} {p} {o} ." for s, p, o in delete) + " } }")
    if insert:
        parts.append(f"INSERT DATA {{ GRAPH {g} {{ " + " ".join(f"{s} {p} {o} ." for s, p, o in insert) + " } }")
    return " ;\n".join(parts) or None


# --- back from RDF -----------------------------------------------------------------------

def _py_value(term: Any) -> Any:
    if not isinstance(term, ox.Literal):
        raise ValueError(f"not a literal: {term}")
    datatype = term.datatype.value
    text = term.value
    if datatype == XSD_BOOLEAN:
        return text == "true"
    if datatype == XSD_INTEGER:
        return int(text)
    if datatype == XSD_DOUBLE:
        return float(text)
    if datatype == RDF_JSON:
        return json.loads(text)
    if datatype == XSD_DATETIME:  # Oxigraph keeps the canonical form (no ".000"): back to Orion's
        date = parse_datetime(text)
        return render_datetime(date) if date is not None else text
    return text


def _seconds(term: Any) -> float:
    return datetime.fromisoformat(term.value.replace("Z", "+00:00")).timestamp()


def entities_from_quads(quads: Iterable[Any], service_path: str) -> list[tuple[Entity, str]]:
    """(entity, node) for every entity in ``quads`` (one graph's), oldest first."""
    props: dict[str, dict[str, list[Any]]] = defaultdict(lambda: defaultdict(list))
    for quad in quads:
        subject = quad.subject
        key = subject.value if isinstance(subject, ox.NamedNode) else str(subject)
        props[key][quad.predicate.value].append(quad.object)
    out = []
    for node, p in props.items():
        if str(NGSI.entityId) not in p:
            continue
        attrs: list[tuple[float, str, Attribute]] = []
        for a_term in p.get(str(NGSI.hasAttribute), []):
            a = props.get(a_term.value, {})
            name = a[str(NGSI.name)][0].value
            metadata = {}
            for m_term in a.get(str(NGSI.hasMetadata), []):
                m = props.get(m_term.value, {})
                metadata[m[str(NGSI.name)][0].value] = {"type": m[str(NGSI.metadataType)][0].value,
                                                        "value": _py_value(m[str(NGSI.hasValue)][0])}
            created = _seconds(a[str(NGSI.dateCreated)][0])
            attrs.append((created, name, Attribute(a[str(NGSI.attributeType)][0].value,
                                                   _py_value(a[str(NGSI.hasValue)][0]), metadata,
                                                   created, _seconds(a[str(NGSI.dateModified)][0]))))
        attrs.sort(key=lambda item: (item[0], item[1]))
        entity = Entity.make(p[str(NGSI.entityId)][0].value, p[str(NGSI.entityType)][0].value,
                             service_path, {name: attr for _, name, attr in attrs},
                             _seconds(p[str(NGSI.dateCreated)][0]), _seconds(p[str(NGSI.dateModified)][0]))
        out.append((entity, node))
    out.sort(key=lambda item: (item[0].created, item[0].id, item[0].type))
    return out

