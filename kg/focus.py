"""Which nodes a shape targets (its focus nodes), decided once per validation and shared by shapes.

Why: the fast validator used to join every constraint's query with the shape's focus pattern
(``?this rdf:type/rdfs:subClassOf* C`` and the like). On a 100k-resource plant that pattern alone
costs ~0.15–0.45 s per query and was evaluated anew by each of ~80 queries. Most constraint queries
bind ``?this`` themselves (a property shape's path, a SHACL-SPARQL constraint's own triple pattern),
and return only the violating rows, which are few. Those queries now run without the focus pattern
and :class:`Focus` keeps the rows whose ``?this`` is a focus node: per row (a few index look-ups)
while rows are few, by one query for the whole set (computed once, then shared by every shape with
the same targets) when they are many.

Membership follows SHACL §2.1.3 exactly as the focus pattern of :mod:`kg.shacl_sparql` states it:
a SHACL instance of a target class is a node with an ``rdf:type`` whose ``rdfs:subClassOf*`` reaches
the class; a subjects-of/objects-of target holds a node with such a triple; a target node is always
a focus node.
"""

from __future__ import annotations

from typing import Iterable

import pyoxigraph as ox

from kg.namespaces import RDF, RDFS

_TYPE = ox.NamedNode(str(RDF.type))
_SUBCLASS = f"<{RDFS.subClassOf}>"
#: Past this many per-row checks for one target list, its whole focus set is computed instead.
ROWS_BEFORE_SET = 2000
#: From this many focus nodes (estimated) on, a query that binds ``?this`` runs without the focus
#: pattern: joining a few focus nodes is cheaper than scanning every value of a predicate.
LARGE = 1000

Term = ox.NamedNode | ox.BlankNode | ox.Literal


class Focus:
    """Focus-node membership over one store and dataset (the graphs the queries read).

    ``graphs`` None means the union of every graph of the store (what the validator's queries
    read by default); else the listed named graphs.
    """

    def __init__(self, store: ox.Store, graphs: list[ox.NamedNode] | None, options: dict[str, object]) -> None:
        self.store = store
        self.graphs = graphs
        self.options = options
        self._subclasses: dict[str, frozenset[ox.NamedNode]] = {}
        self._sets: dict[str, frozenset[Term]] = {}
        self._checks: dict[str, int] = {}
        self._estimates: dict[str, int] = {}

    # -- the dataset ---------------------------------------------------------------------------
    def _quads(self, s: Term | None, p: ox.NamedNode, o: Term | None) -> Iterable[ox.Quad]:
        if self.graphs is None:
            return self.store.quads_for_pattern(s, p, o, None)  # type: ignore[arg-type]
        return (q for g in self.graphs for q in self.store.quads_for_pattern(s, p, o, g))  # type: ignore[arg-type]

    def subclasses(self, cls: str) -> frozenset[ox.NamedNode]:
        """``cls`` and every class whose ``rdfs:subClassOf*`` reaches it."""
        found = self._subclasses.get(cls)
        if found is None:
            rows = self.store.query(f"SELECT ?c WHERE {{ ?c {_SUBCLASS}* {ox.NamedNode(cls)} }}",
                                    **self.options)  # type: ignore[arg-type]
            found = frozenset(r["c"] for r in rows if isinstance(r["c"], ox.NamedNode)) | {ox.NamedNode(cls)}
            self._subclasses[cls] = found
        return found

    def estimate(self, key: str, targets: list[tuple[str, object]]) -> int:
        """How many focus nodes ``targets`` hold, up to :data:`LARGE` (at least 1), by ``LIMIT`` probes
        (a count of triples, not of distinct nodes: 0 exactly when there is none)."""
        if key not in self._estimates:
            cap, total = max(LARGE, 1), 0  # at least 1: whether there is any at all
            for kind, value in targets:
                if total >= cap:
                    break
                total += self._probe(kind, value, cap - total)
            self._estimates[key] = total
        return self._estimates[key]

    def is_large(self, key: str, targets: list[tuple[str, object]]) -> bool:
        """Whether ``targets`` hold at least :data:`LARGE` focus nodes (estimated)."""
        return self.estimate(key, targets) >= LARGE

    def is_empty(self, key: str, targets: list[tuple[str, object]]) -> bool:
        """Whether ``targets`` hold no focus node at all: a shape without focus nodes has no
        results (SHACL §2.1), so its queries need not run. Most shapes of a small plant are so
        (no AGV, no Kafka cluster...)."""
        return self.estimate(key, targets) == 0

    def _probe(self, kind: str, value: object, limit: int) -> int:
        if kind == "targetNode":
            return 1
        if kind == "targetClass":
            classes = " ".join(str(c) for c in self.subclasses(str(value)))
            where = f"VALUES ?c {{ {classes} }} ?x {_TYPE} ?c ."
        elif kind == "targetSubjectsOf":
            where = f"?x {ox.NamedNode(str(value))} ?o ."
        else:
            where = f"?o {ox.NamedNode(str(value))} ?x ."
        rows = self.store.query(f"SELECT ?x WHERE {{ {where} }} LIMIT {limit}", **self.options)  # type: ignore[arg-type]
        return sum(1 for _ in rows)

    # -- membership ----------------------------------------------------------------------------
    def contains(self, key: str, pattern: str, targets: list[tuple[str, object]], node: Term) -> bool:
        """Whether ``node`` is a focus node of ``targets`` (kind, IRI text) — ``pattern`` is the
        same targets as a SPARQL group binding ``?this`` and ``key`` names them for caching."""
        if key in self._sets:
            return node in self._sets[key]
        count = self._checks.get(key, 0) + 1
        self._checks[key] = count
        if count > ROWS_BEFORE_SET:
            rows = self.store.query(f"SELECT DISTINCT ?this WHERE {{ {pattern} }}", **self.options)  # type: ignore[arg-type]
            self._sets[key] = frozenset(r["this"] for r in rows)
            return node in self._sets[key]
        return any(self._one(kind, value, node) for kind, value in targets)

    def _one(self, kind: str, value: object, node: Term) -> bool:
        if kind == "targetNode":
            return node == value
        if isinstance(node, ox.Literal) and kind != "targetObjectsOf":
            return False
        if kind == "targetClass":
            classes = self.subclasses(str(value))
            return any(q.object in classes for q in self._quads(node, _TYPE, None))
        pred = ox.NamedNode(str(value))
        if kind == "targetSubjectsOf":
            return any(True for _ in self._quads(node, pred, None))
        if kind == "targetObjectsOf":
            return any(True for _ in self._quads(None, pred, node))
        raise AssertionError(kind)
