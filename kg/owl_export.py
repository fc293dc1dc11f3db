"""Export the Turtle ontology to RDF/XML (``ontology/plantkg.owl``) for tools that prefer it.

Why a writer of our own: rdflib's RDF/XML serializers order namespaces by hash (so the file changes
from run to run) and print random blank-node labels. This one writes the same bytes for the same
graph: blank nodes get canonical labels (``rdflib.compare``), subjects and predicates are sorted,
blank nodes used once are nested in place (restrictions, ``owl:intersectionOf`` lists as
``rdf:parseType="Collection"``), the way Protégé writes RDF/XML. ``python -m kg.owl_export``
regenerates the repository copy; a test checks that copy is isomorphic to the Turtle.
"""

from __future__ import annotations

import argparse
import re
from collections import Counter
from pathlib import Path
from xml.sax.saxutils import escape, quoteattr

from rdflib import BNode, Graph, Literal, URIRef
from rdflib.compare import to_canonical_graph
from rdflib.term import Node

from kg.namespaces import OWL, RDF

_NCNAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_.\-]*$")
#: Order of top-level subjects by their type, so the file reads like the Turtle.
#: Annotation properties come before the header: the OWL API 3 parser (HermiT's) drops an ontology
#: annotation whose property it has not seen declared yet.
_TYPE_RANK = [
    OWL.AnnotationProperty,
    OWL.Ontology,
    OWL.Class,
    OWL.ObjectProperty,
    OWL.DatatypeProperty,
    OWL.NamedIndividual,
]


class _Writer:
    """Writes one canonicalized graph as RDF/XML; see the module docstring for the layout."""

    def __init__(self, graph: Graph) -> None:
        self.g = graph
        self.prefixes: dict[str, str] = {}  # namespace -> prefix
        for prefix, ns in sorted(graph.namespaces()):
            if prefix and str(ns) not in self.prefixes:
                self.prefixes[str(ns)] = prefix
        refs = Counter(o for _, _, o in graph if isinstance(o, BNode))
        self.inline = {b for b, n in refs.items() if n == 1}
        self.shared = {b for b, n in refs.items() if n > 1}
        self.lines: list[str] = []
        self.used: set[str] = {"rdf"}

    # -- names ---------------------------------------------------------------------------------
    def qname(self, iri: URIRef) -> str:
        text = str(iri)
        cut = max(text.rfind("#"), text.rfind("/"))
        ns, local = text[: cut + 1], text[cut + 1 :]
        if not _NCNAME.match(local):
            raise ValueError(f"{iri} cannot be written as an RDF/XML element name")
        if ns not in self.prefixes:
            self.prefixes[ns] = f"ns{len(self.prefixes)}"
        prefix = self.prefixes[ns]
        self.used.add(prefix)
        return f"{prefix}:{local}"

    # -- nodes ---------------------------------------------------------------------------------
    def _list_items(self, node: Node) -> list[Node] | None:
        """The members of a well-formed RDF list of resources used once, else None."""
        items: list[Node] = []
        while node != RDF.nil:
            if not isinstance(node, BNode) or node not in self.inline:
                return None
            preds = sorted(self.g.predicates(node, None))
            first = list(self.g.objects(node, RDF.first))
            rest = list(self.g.objects(node, RDF.rest))
            if preds != sorted([RDF.first, RDF.rest]) or len(first) != 1 or len(rest) != 1:
                return None
            if isinstance(first[0], Literal):
                return None
            items.append(first[0])
            node = rest[0]
        return items

    def node(self, subject: Node, indent: int, top_level: bool) -> None:
        pad = "  " * indent
        types = sorted((t for t in self.g.objects(subject, RDF.type) if isinstance(t, URIRef)), key=_type_key)
        element = self.qname(types[0]) if types else "rdf:Description"
        if isinstance(subject, URIRef):
            ident = f" rdf:about={quoteattr(str(subject))}"
        elif top_level and subject in self.shared:
            ident = f" rdf:nodeID={quoteattr(str(subject))}"
        else:
            ident = ""
        arcs = [
            (p, o)
            for p, o in self.g.predicate_objects(subject)
            if not (types and p == RDF.type and o == types[0])
        ]
        if not arcs:
            self.lines.append(f"{pad}<{element}{ident}/>")
            return
        self.lines.append(f"{pad}<{element}{ident}>")
        for p, o in sorted(arcs, key=lambda po: (self.qname(po[0]), _sort_key(po[1]))):
            self.arc(p, o, indent + 1)
        self.lines.append(f"{pad}</{element}>")

    def arc(self, predicate: URIRef, obj: Node, indent: int) -> None:
        pad = "  " * indent
        name = self.qname(predicate)
        if isinstance(obj, Literal):
            if obj.datatype == RDF.XMLLiteral:
                raise ValueError("rdf:XMLLiteral values are not supported by the exporter")
            attrs = ""
            if obj.language:
                attrs = f" xml:lang={quoteattr(obj.language)}"
            elif obj.datatype is not None:
                attrs = f" rdf:datatype={quoteattr(str(obj.datatype))}"
            self.lines.append(f"{pad}<{name}{attrs}>{escape(str(obj))}</{name}>")
        elif isinstance(obj, URIRef):
            self.lines.append(f"{pad}<{name} rdf:resource={quoteattr(str(obj))}/>")
        elif obj in self.inline:
            items = self._list_items(obj)
            if items is not None:
                self.lines.append(f'{pad}<{name} rdf:parseType="Collection">')
                for item in items:
                    self.member(item, indent + 1)
                self.lines.append(f"{pad}</{name}>")
            else:
                self.lines.append(f"{pad}<{name}>")
                self.node(obj, indent + 1, top_level=False)
                self.lines.append(f"{pad}</{name}>")
        else:
            self.lines.append(f"{pad}<{name} rdf:nodeID={quoteattr(str(obj))}/>")

    def member(self, item: Node, indent: int) -> None:
        if isinstance(item, URIRef):
            self.lines.append(f"{'  ' * indent}<rdf:Description rdf:about={quoteattr(str(item))}/>")
        elif item in self.inline:
            self.node(item, indent, top_level=False)
        else:
            self.lines.append(f"{'  ' * indent}<rdf:Description rdf:nodeID={quoteattr(str(item))}/>")

    # -- document ------------------------------------------------------------------------------
    def document(self) -> str:
        subjects = {s for s in self.g.subjects() if not (isinstance(s, BNode) and s in self.inline)}
        for subject in sorted(subjects, key=self._subject_key):
            self.node(subject, 1, top_level=True)
            self.lines.append("")
        body = self.lines[:-1] if self.lines and self.lines[-1] == "" else self.lines
        by_prefix = {p: ns for ns, p in self.prefixes.items() if p in self.used}
        by_prefix["rdf"] = str(RDF)
        decls = [f"    xmlns:{p}={quoteattr(ns)}" for p, ns in sorted(by_prefix.items())]
        head = ['<?xml version="1.0" encoding="utf-8"?>', "<rdf:RDF", *decls]
        head[-1] += ">"
        return "\n".join([*head, *body, "</rdf:RDF>", ""])

    def _subject_key(self, subject: Node) -> tuple[int, int, str]:
        ranks = [_TYPE_RANK.index(t) for t in self.g.objects(subject, RDF.type) if t in _TYPE_RANK]
        rank = min(ranks) if ranks else len(_TYPE_RANK)
        return (isinstance(subject, BNode), rank, str(subject))


def _type_key(node: Node) -> tuple[int, str]:
    """Main types first (owl:ObjectProperty before owl:IrreflexiveProperty), then by IRI."""
    rank = _TYPE_RANK.index(node) if node in _TYPE_RANK else len(_TYPE_RANK)
    return (rank, str(node))


def _sort_key(node: Node) -> tuple[int, str, str]:
    if isinstance(node, Literal):
        return (2, str(node), f"{node.language or ''}{node.datatype or ''}")
    return (1 if isinstance(node, BNode) else 0, str(node), "")


def to_rdfxml(graph: Graph) -> str:
    """``graph`` as deterministic RDF/XML text (same graph, same text)."""
    canonical = Graph()
    for prefix, ns in graph.namespaces():
        canonical.bind(prefix, ns, override=True, replace=True)
    for triple in to_canonical_graph(graph):
        canonical.add(triple)
    return _Writer(canonical).document()


def export_rdfxml(src: Path, dst: Path) -> None:
    """Read the Turtle ontology ``src`` and write its RDF/XML copy to ``dst``."""
    graph = Graph()
    graph.parse(Path(src), format="turtle")
    text = to_rdfxml(graph)
    Path(dst).write_text(text, encoding="utf-8", newline="\n")


def main(argv: list[str] | None = None) -> int:
    """CLI: regenerate ``ontology/plantkg.owl`` from ``ontology/plantkg.ttl`` (or given paths)."""
    root = Path(__file__).resolve().parent.parent / "ontology"
    parser = argparse.ArgumentParser(prog="python -m kg.owl_export", description=main.__doc__)
    parser.add_argument("src", nargs="?", type=Path, default=root / "plantkg.ttl")
    parser.add_argument("dst", nargs="?", type=Path, default=root / "plantkg.owl")
    args = parser.parse_args(argv)
    export_rdfxml(args.src, args.dst)
    print(f"wrote {args.dst}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
