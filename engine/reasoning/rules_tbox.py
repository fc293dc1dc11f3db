"""Read the TBox — OWL axioms and SWRL rules — out of a loaded plant, into plain Python values.

The fast reasoner (:mod:`engine.reasoning.rules_fast`) compiles these values to SPARQL; nothing about the
plant's rules is written in Python. The reader knows a fixed set of constructs (see
``SUPPORTED_PREDICATES`` / ``SUPPORTED_TYPES`` and the class-expression grammar below) and refuses
every other OWL, RDFS or SWRL construct with :class:`UnsupportedConstructError`, naming it, so no
axiom is silently ignored. Axioms are read from the ontology graph *and* the plant files (a plant
may add axioms of its own); the inferred and observed graphs are not read.

Class expressions: a named class, ``owl:Thing``, ``owl:intersectionOf``, ``owl:unionOf``,
``owl:oneOf`` (named individuals), ``owl:someValuesFrom`` and ``owl:hasValue`` restrictions on a
property or on ``[owl:inverseOf p]``.
Axioms: ``rdfs:subClassOf``, ``owl:equivalentClass``, ``owl:disjointWith``,
``owl:AllDisjointClasses``, ``rdfs:subPropertyOf``, ``owl:equivalentProperty``, ``owl:inverseOf``,
``rdfs:domain``, ``rdfs:range``, ``owl:IrreflexiveProperty``, ``owl:FunctionalProperty``, SWRL ``swrl:Imp`` with class, individual-property, data-valued-property and
different-individuals atoms. ``owl:AllDifferent`` / ``owl:differentFrom`` are accepted: plants are
read under the unique-name assumption (distinct IRIs, distinct things) anyway.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Iterable, Union

import pyoxigraph as ox

from engine.reasoning.rules_errors import UnsupportedConstructError
from kg.namespaces import OWL, RDF, RDFS, SWRL, XSD

RESERVED_NAMESPACES = (str(RDF), str(RDFS), str(OWL), str(SWRL), "http://www.w3.org/2003/11/swrlb#")

_T = ox.NamedNode


def _n(term: object) -> ox.NamedNode:
    return ox.NamedNode(str(term))


TYPE = _n(RDF.type)
FIRST, REST, NIL = _n(RDF.first), _n(RDF.rest), _n(RDF.nil)

#: Predicates of the reserved namespaces the reader understands (annotations included).
SUPPORTED_PREDICATES = frozenset(str(p) for p in (
    RDF.type, RDF.first, RDF.rest,
    RDFS.label, RDFS.comment, RDFS.seeAlso, RDFS.isDefinedBy,
    RDFS.subClassOf, RDFS.subPropertyOf, RDFS.domain, RDFS.range,
    OWL.equivalentClass, OWL.equivalentProperty, OWL.inverseOf, OWL.intersectionOf, OWL.unionOf,
    OWL.onProperty, OWL.someValuesFrom, OWL.hasValue, OWL.oneOf, OWL.disjointWith, OWL.members,
    OWL.distinctMembers, OWL.differentFrom,
    OWL.imports, OWL.versionInfo, OWL.versionIRI, OWL.priorVersion, OWL.backwardCompatibleWith,
    OWL.incompatibleWith, OWL.deprecated, OWL.annotatedSource, OWL.annotatedProperty,
    OWL.annotatedTarget,
    SWRL.body, SWRL.head, SWRL.classPredicate, SWRL.propertyPredicate, SWRL.argument1, SWRL.argument2,
))

#: Types of the reserved namespaces the reader understands.
SUPPORTED_TYPES = frozenset(str(t) for t in (
    OWL.Class, RDFS.Class, OWL.ObjectProperty, OWL.DatatypeProperty, OWL.AnnotationProperty,
    OWL.NamedIndividual, OWL.Thing, OWL.Ontology, OWL.Restriction, OWL.FunctionalProperty,
    OWL.IrreflexiveProperty, OWL.AllDisjointClasses, OWL.AllDifferent, OWL.Axiom, RDFS.Datatype,
    RDF.List, RDF.Property,
    SWRL.Imp, SWRL.Variable, SWRL.AtomList, SWRL.ClassAtom, SWRL.IndividualPropertyAtom,
    SWRL.DatavaluedPropertyAtom, SWRL.DifferentIndividualsAtom,
))

#: Datatypes a data range or a data ``someValuesFrom`` may name: the literal datatypes each admits.
_INTEGER_TYPES = tuple(str(XSD[t]) for t in (
    "integer", "long", "int", "short", "byte", "nonNegativeInteger", "positiveInteger",
    "nonPositiveInteger", "negativeInteger", "unsignedLong", "unsignedInt", "unsignedShort",
    "unsignedByte"))
DATATYPES: dict[str, tuple[str, ...] | None] = {
    str(RDFS.Literal): None,  # any literal
    str(XSD.string): (str(XSD.string),),
    str(XSD.boolean): (str(XSD.boolean),),
    str(XSD.integer): _INTEGER_TYPES,
    str(XSD.decimal): (str(XSD.decimal), *_INTEGER_TYPES),
    str(XSD.double): (str(XSD.double),),
    str(XSD.float): (str(XSD.float),),
    str(XSD.dateTime): (str(XSD.dateTime), str(XSD.dateTimeStamp)),
    str(XSD.anyURI): (str(XSD.anyURI),),
}


# --- values ---------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Prop:
    """A property expression: a named property, or its inverse."""

    iri: str
    inverse: bool = False


@dataclass(frozen=True)
class Thing:
    """``owl:Thing``."""


@dataclass(frozen=True)
class Named:
    iri: str


@dataclass(frozen=True)
class And:
    parts: tuple["Expr", ...]


@dataclass(frozen=True)
class Or:
    parts: tuple["Expr", ...]


@dataclass(frozen=True)
class Some:
    prop: Prop
    filler: "Expr"


@dataclass(frozen=True)
class HasValue:
    prop: Prop
    value: ox.NamedNode | ox.Literal


@dataclass(frozen=True)
class OneOf:
    """An enumeration of named individuals (``owl:oneOf``)."""

    members: tuple[ox.NamedNode, ...]


@dataclass(frozen=True)
class Datatype:
    """A datatype used as the filler of a data ``someValuesFrom``."""

    iri: str


Expr = Union[Thing, Named, And, Or, Some, HasValue, OneOf, Datatype]


@dataclass(frozen=True)
class Var:
    """A SWRL variable (``swrl:Variable``), by its IRI."""

    iri: str

    @property
    def local(self) -> str:
        return self.iri.rsplit("#", 1)[-1].rsplit("/", 1)[-1].rsplit(":", 1)[-1]


Arg = Union[Var, ox.NamedNode, ox.Literal]


@dataclass(frozen=True)
class Atom:
    """One SWRL atom: ``kind`` is class, object, data or different."""

    kind: str
    predicate: str | None
    args: tuple[Arg, ...]


@dataclass(frozen=True)
class Rule:
    """A SWRL rule (``swrl:Imp``): ``head`` holds when every atom of ``body`` does."""

    name: str
    body: tuple[Atom, ...]
    head: tuple[Atom, ...]


@dataclass(frozen=True)
class TBox:
    """Every axiom the fast engine acts on (equivalences appear as two sub-class pairs)."""

    object_properties: frozenset[str]
    data_properties: frozenset[str]
    subclass: tuple[tuple[Expr, Expr], ...] = ()
    subproperty: tuple[tuple[Prop, Prop], ...] = ()
    domains: tuple[tuple[str, Expr], ...] = ()
    ranges: tuple[tuple[str, Expr], ...] = ()
    data_ranges: tuple[tuple[str, str], ...] = ()
    disjoint: tuple[tuple[Expr, ...], ...] = ()
    irreflexive: tuple[str, ...] = ()
    functional_data: tuple[str, ...] = ()
    functional_object: tuple[str, ...] = ()
    rules: tuple[Rule, ...] = ()


# --- reading --------------------------------------------------------------------------------------

class _Reader:
    """Triple look-ups over the input graphs, and the refusal messages."""

    def __init__(self, store: ox.Store, graphs: list[ox.NamedNode], where: Callable[[object], str]) -> None:
        self.store = store
        self.graphs = graphs
        self.where = where

    def objects(self, s: object, p: ox.NamedNode) -> list[object]:
        out: list[object] = []
        for g in self.graphs:
            for q in self.store.quads_for_pattern(s, p, None, g):  # type: ignore[arg-type]
                if q.object not in out:
                    out.append(q.object)
        return out

    def one(self, s: object, p: ox.NamedNode) -> object | None:
        values = self.objects(s, p)
        if len(values) > 1:
            raise UnsupportedConstructError(f"several {_short(p)} values on one node", self.where(s))
        return values[0] if values else None

    def triples(self, p: ox.NamedNode, o: object | None = None) -> list[tuple[object, object]]:
        out: list[tuple[object, object]] = []
        seen: set[tuple[object, object]] = set()
        for g in self.graphs:
            for q in self.store.quads_for_pattern(None, p, o, g):  # type: ignore[arg-type]
                pair = (q.subject, q.object)
                if pair not in seen:
                    seen.add(pair)
                    out.append(pair)
        return out

    def subjects(self, p: ox.NamedNode, o: object) -> list[object]:
        return [s for s, _ in self.triples(p, o)]

    def items(self, node: object) -> list[object]:
        """The members of an RDF list."""
        out: list[object] = []
        seen: set[object] = set()
        while node != NIL:
            if node in seen or not isinstance(node, ox.BlankNode):
                raise UnsupportedConstructError("a malformed RDF list", self.where(node))
            seen.add(node)
            first, rest = self.one(node, FIRST), self.one(node, REST)
            if first is None or rest is None:
                raise UnsupportedConstructError("a malformed RDF list", self.where(node))
            out.append(first)
            node = rest
        return out


def _short(term: object) -> str:
    text = term.value if isinstance(term, (ox.NamedNode, ox.BlankNode)) else str(term)
    for prefix, ns in (("owl:", OWL), ("rdfs:", RDFS), ("rdf:", RDF), ("swrl:", SWRL), ("xsd:", XSD)):
        if text.startswith(str(ns)):
            return prefix + text[len(str(ns)):]
    return f"<{text}>" if isinstance(term, ox.NamedNode) else str(term)


def _reserved(iri: str) -> bool:
    return iri.startswith(RESERVED_NAMESPACES)


def dataset_options(store: ox.Store, graphs: list[ox.NamedNode]) -> dict[str, object]:
    """Query options making ``graphs`` the default graph. Oxigraph answers ~30 % faster over its
    union default graph than over a list of graphs, so that is used when the store holds nothing
    else (no observed graph, no triple in the default graph)."""
    others = set(store.named_graphs()) - set(graphs)
    default_empty = next(iter(store.quads_for_pattern(None, None, None, ox.DefaultGraph())), None) is None
    if not others and default_empty:
        return {"use_default_graph_as_union": True}
    return {"default_graph": list(graphs)}


def scan_vocabulary(store: ox.Store, graphs: list[ox.NamedNode], where: Callable[[object], str],
                    annotation_properties: Iterable[str]) -> None:
    """Refuse any type or predicate of the OWL/RDFS/SWRL namespaces the reader does not know, and
    anonymous (blank-node) individuals. One pass over the types, one over all triples."""
    annotations = set(annotation_properties)
    options = dataset_options(store, graphs)
    # Results are read whole (list): a check raises mid-loop, and an Oxigraph result left
    # half-read must not be dropped later on another thread (it is not sendable).
    rows = list(store.query(
        "SELECT ?c (SUM(IF(isBlank(?s), 1, 0)) AS ?blank) (SAMPLE(?s) AS ?x) "
        "WHERE { ?s a ?c } GROUP BY ?c", **options))  # type: ignore[arg-type]
    for row in rows:
        c = row["c"]
        if isinstance(c, ox.BlankNode):
            raise UnsupportedConstructError("a class expression asserted as a type", where(row["x"]),
                                            hint="name the class in the ontology and assert that")
        if not isinstance(c, ox.NamedNode):
            raise UnsupportedConstructError(f"rdf:type {c}", where(row["x"]))
        if _reserved(c.value):
            if c.value not in SUPPORTED_TYPES:
                raise UnsupportedConstructError(_short(c), where(row["x"]))
        elif int(row["blank"].value):
            raise UnsupportedConstructError(f"an anonymous individual (a blank node) of <{c.value}>",
                                            where(row["x"]), hint="give the individual an IRI")
    rows = list(store.query(
        "SELECT ?p (SUM(IF(isBlank(?s) || isBlank(?o), 1, 0)) AS ?blank) "
        "(SAMPLE(?s) AS ?x) WHERE { ?s ?p ?o } GROUP BY ?p", **options))  # type: ignore[arg-type]
    for row in rows:
        p = row["p"].value
        if _reserved(p):
            if p not in SUPPORTED_PREDICATES:
                raise UnsupportedConstructError(_short(row["p"]), where(row["x"]))
        elif int(row["blank"].value) and p not in annotations:
            sample = list(store.query(
                f"SELECT ?s WHERE {{ ?s {row['p']} ?o FILTER(isBlank(?s) || isBlank(?o)) }} LIMIT 1",
                **options))[0]["s"]  # type: ignore[arg-type]
            raise UnsupportedConstructError(
                f"an anonymous individual (a blank node) used with <{p}>", where(sample),
                hint="give the individual an IRI; the fast engine reasons over named individuals")


def read_tbox(store: ox.Store, graphs: list[ox.NamedNode], where: Callable[[object], str]) -> TBox:
    """Every supported axiom of ``graphs``; :class:`UnsupportedConstructError` for anything else."""
    r = _Reader(store, graphs, where)
    ann = {s.value for s in r.subjects(TYPE, _n(OWL.AnnotationProperty)) if isinstance(s, ox.NamedNode)}
    scan_vocabulary(store, graphs, where, ann)

    obj = {s.value for s in r.subjects(TYPE, _n(OWL.ObjectProperty)) if isinstance(s, ox.NamedNode)}
    dat = {s.value for s in r.subjects(TYPE, _n(OWL.DatatypeProperty)) if isinstance(s, ox.NamedNode)}
    both = obj & dat
    if both:
        raise UnsupportedConstructError("a property declared both object and data property",
                                        where(ox.NamedNode(sorted(both)[0])))

    def prop(node: object) -> Prop:
        if isinstance(node, ox.NamedNode):
            if node.value not in obj and node.value not in dat:
                raise UnsupportedConstructError(f"the undeclared property <{node.value}>", where(node),
                                                hint="declare it as owl:ObjectProperty or owl:DatatypeProperty")
            return Prop(node.value)
        inner = r.one(node, _n(OWL.inverseOf))
        if isinstance(node, ox.BlankNode) and isinstance(inner, ox.NamedNode) and inner.value in obj:
            return Prop(inner.value, inverse=True)
        raise UnsupportedConstructError("a property expression other than a property or its inverse",
                                        where(node))

    memo: dict[object, Expr] = {}

    def expr(node: object, *, data: bool = False) -> Expr:
        if node in memo:
            return memo[node]
        if isinstance(node, ox.NamedNode):
            if node.value == str(OWL.Thing):
                return Thing()
            if node.value == str(OWL.Nothing):
                raise UnsupportedConstructError("owl:Nothing", where(node))
            if data or node.value in DATATYPES:
                if node.value not in DATATYPES:
                    raise UnsupportedConstructError(f"the datatype <{node.value}>", where(node))
                return Datatype(node.value)
            return Named(node.value)
        if not isinstance(node, ox.BlankNode):
            raise UnsupportedConstructError(f"{node} as a class", "the ontology")
        memo[node] = Thing()  # a cycle of blank nodes reads as Thing rather than looping
        inter, union = r.one(node, _n(OWL.intersectionOf)), r.one(node, _n(OWL.unionOf))
        on, one_of = r.one(node, _n(OWL.onProperty)), r.one(node, _n(OWL.oneOf))
        some, value = r.one(node, _n(OWL.someValuesFrom)), r.one(node, _n(OWL.hasValue))
        result: Expr
        if one_of is not None and inter is None and union is None and on is None:
            members = r.items(one_of)
            if not all(isinstance(m, ox.NamedNode) for m in members):
                raise UnsupportedConstructError("owl:oneOf of literals or anonymous individuals", where(node))
            result = OneOf(tuple(members))  # type: ignore[arg-type]
        elif inter is not None and union is None and on is None:
            result = And(tuple(expr(m) for m in r.items(inter)))
        elif union is not None and inter is None and on is None:
            result = Or(tuple(expr(m) for m in r.items(union)))
        elif on is not None and (some is None) != (value is None):
            p = prop(on)
            if some is not None:
                result = Some(p, expr(some, data=p.iri in dat))
            else:
                if not isinstance(value, (ox.NamedNode, ox.Literal)):
                    raise UnsupportedConstructError("owl:hasValue with an anonymous individual", where(node))
                if (p.iri in dat) != isinstance(value, ox.Literal):
                    raise UnsupportedConstructError("owl:hasValue whose value does not fit the property", where(node))
                result = HasValue(p, value)
        else:
            raise UnsupportedConstructError("a class expression other than a named class, "
                                            "intersectionOf, unionOf, someValuesFrom or hasValue", where(node))
        memo[node] = result
        return result

    subclass: list[tuple[Expr, Expr]] = []
    for s, o in r.triples(_n(RDFS.subClassOf)):
        subclass.append((expr(s), expr(o)))
    for s, o in r.triples(_n(OWL.equivalentClass)):
        a, b = expr(s), expr(o)
        subclass += [(a, b), (b, a)]

    disjoint: list[tuple[Expr, ...]] = []
    for s, o in r.triples(_n(OWL.disjointWith)):
        disjoint.append((expr(s), expr(o)))
    for node in r.subjects(TYPE, _n(OWL.AllDisjointClasses)):
        members = r.one(node, _n(OWL.members))
        if members is None:
            raise UnsupportedConstructError("owl:AllDisjointClasses without owl:members", where(node))
        disjoint.append(tuple(expr(m) for m in r.items(members)))

    def annotation(*nodes: object) -> bool:
        """Axioms about annotation properties carry no meaning for reasoning (OWL 2 DL)."""
        return any(isinstance(n, ox.NamedNode) and n.value in ann for n in nodes)

    subproperty: list[tuple[Prop, Prop]] = []
    for s, o in r.triples(_n(RDFS.subPropertyOf)):
        if not annotation(s, o):
            subproperty.append((prop(s), prop(o)))
    for s, o in r.triples(_n(OWL.equivalentProperty)):
        if not annotation(s, o):
            subproperty += [(prop(s), prop(o)), (prop(o), prop(s))]
    for s, o in r.triples(_n(OWL.inverseOf)):
        if isinstance(s, ox.BlankNode):
            continue  # a property expression, read where it is used
        a, b = prop(s), prop(o)
        if a.iri not in obj or b.iri not in obj:
            raise UnsupportedConstructError("owl:inverseOf between non-object properties", where(s))
        subproperty += [(a, Prop(b.iri, True)), (Prop(b.iri, True), a)]
    for a, b in subproperty:
        if (a.iri in obj) != (b.iri in obj):
            raise UnsupportedConstructError("a sub-property axiom between an object and a data property",
                                            where(ox.NamedNode(a.iri)))

    domains: list[tuple[str, Expr]] = []
    for s, o in r.triples(_n(RDFS.domain)):
        if not annotation(s):
            domains.append((prop(s).iri, expr(o)))
    ranges: list[tuple[str, Expr]] = []
    data_ranges: list[tuple[str, str]] = []
    for s, o in r.triples(_n(RDFS.range)):
        if annotation(s):
            continue
        p = prop(s)
        if p.iri in dat:
            dt = expr(o, data=True)
            if not isinstance(dt, Datatype):
                raise UnsupportedConstructError("a data range other than a datatype", where(s))
            data_ranges.append((p.iri, dt.iri))
        else:
            rng = expr(o)
            if isinstance(rng, Datatype):
                raise UnsupportedConstructError("a datatype as the range of an object property", where(s))
            ranges.append((p.iri, rng))

    irreflexive = sorted(prop(s).iri for s in r.subjects(TYPE, _n(OWL.IrreflexiveProperty)))
    functional, functional_obj = [], []
    for s in r.subjects(TYPE, _n(OWL.FunctionalProperty)):
        p = prop(s)
        # On an object property two values would be made equal; under the unique-name
        # assumption two named values are a contradiction instead: a constraint either way.
        (functional_obj if p.iri in obj else functional).append(p.iri)

    rules = tuple(_read_rule(r, node, obj, dat, expr) for node in r.subjects(TYPE, _n(SWRL.Imp)))
    return TBox(
        object_properties=frozenset(obj), data_properties=frozenset(dat),
        subclass=tuple(subclass), subproperty=tuple(subproperty), domains=tuple(domains),
        ranges=tuple(ranges), data_ranges=tuple(data_ranges), disjoint=tuple(disjoint),
        irreflexive=tuple(irreflexive), functional_data=tuple(sorted(functional)),
        functional_object=tuple(sorted(functional_obj)),
        rules=tuple(sorted(rules, key=lambda x: x.name)),
    )


def _read_rule(r: _Reader, node: object, obj: set[str], dat: set[str], expr: Callable[..., Expr]) -> Rule:
    variables = set(r.subjects(TYPE, _n(SWRL.Variable)))
    label = r.one(node, _n(RDFS.label))
    name = label.value if isinstance(label, ox.Literal) else str(node)
    where = f"SWRL rule {name!r}"

    def arg(value: object) -> Arg:
        if isinstance(value, ox.NamedNode):
            return Var(value.value) if value in variables else value
        if isinstance(value, ox.Literal):
            return value
        raise UnsupportedConstructError("a SWRL argument that is an anonymous individual", where)

    def atoms(list_node: object | None) -> tuple[Atom, ...]:
        if list_node is None:
            raise UnsupportedConstructError("a SWRL rule without body or head", where)
        out = []
        for a in r.items(list_node):
            kinds = {t.value for t in r.objects(a, TYPE) if isinstance(t, ox.NamedNode)}
            a1, a2 = r.one(a, _n(SWRL.argument1)), r.one(a, _n(SWRL.argument2))
            if str(SWRL.ClassAtom) in kinds:
                cls = r.one(a, _n(SWRL.classPredicate))
                if not isinstance(cls, ox.NamedNode) or not isinstance(expr(cls), Named):
                    raise UnsupportedConstructError("a SWRL class atom on a class expression "
                                                    "(name the class in the ontology)", where)
                out.append(Atom("class", cls.value, (arg(a1),)))
            elif str(SWRL.IndividualPropertyAtom) in kinds or str(SWRL.DatavaluedPropertyAtom) in kinds:
                p = r.one(a, _n(SWRL.propertyPredicate))
                data = str(SWRL.DatavaluedPropertyAtom) in kinds
                if not isinstance(p, ox.NamedNode) or p.value not in (dat if data else obj):
                    raise UnsupportedConstructError(
                        f"a SWRL {'data-valued' if data else 'individual'} property atom on "
                        f"{p} (not a declared {'data' if data else 'object'} property)", where)
                out.append(Atom("data" if data else "object", p.value, (arg(a1), arg(a2))))
            elif str(SWRL.DifferentIndividualsAtom) in kinds:
                out.append(Atom("different", None, (arg(a1), arg(a2))))
            else:
                kind = ", ".join(sorted(_short(ox.NamedNode(k)) for k in kinds)) or "an untyped atom"
                raise UnsupportedConstructError(f"the SWRL atom {kind}", where)
            if any(x is None for x in out[-1].args):
                raise UnsupportedConstructError("a SWRL atom missing an argument", where)
        return tuple(out)

    body, head = atoms(r.one(node, _n(SWRL.body))), atoms(r.one(node, _n(SWRL.head)))
    bound = {x for a in body if a.kind != "different" for x in a.args if isinstance(x, Var)}
    used = {x for a in (*body, *head) for x in a.args if isinstance(x, Var)}
    if used - bound:
        names = ", ".join(sorted("?" + v.local for v in used - bound))
        raise UnsupportedConstructError(f"a rule that is not DL-safe ({names} not bound by a class or "
                                        "property atom of the body)", where)
    if any(a.kind == "different" for a in head):
        raise UnsupportedConstructError("differentFrom in a rule head", where)
    return Rule(name, body, head)
