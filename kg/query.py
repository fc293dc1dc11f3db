"""SPARQL over a loaded plant: SELECT, ASK, CONSTRUCT and DESCRIBE, read-only, variables bound safely.

Values a caller wants in a query are passed as ``bindings`` (variable name → RDF term) and joined
to the query as a trailing SPARQL ``VALUES`` clause whose terms Oxigraph itself serialises
(N-Triples syntax): a value with a quote or a brace stays one RDF term and cannot change what the
query does. (Oxigraph's own ``substitutions`` only bind projected variables, and not in ASK.) Queries read the union of the plant files, the ontology and any
other graph in the store; the usual prefixes (``pk:``, ``rdf:``, ``rdfs:``, ``owl:``, ``xsd:``,
``sh:``, ``ngsi:``) are predeclared.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Literal as Lit, Mapping

import pyoxigraph as ox

from kg.errors import QueryError
from kg.load import PlantGraph
from kg.namespaces import PREFIXES, XSD

Term = ox.NamedNode | ox.BlankNode | ox.Literal
_POSITION = re.compile(r"^error at (\d+):(\d+): ")
_INTEGER = re.compile(r"^[+-]?[0-9]+$")


@dataclass(frozen=True)
class QueryResult:
    """A query's answer: ``kind`` says which of the other fields are set.

    select: ``variables`` and ``rows`` (terms or None when unbound); ask: ``boolean``;
    construct/describe: ``triples``.
    """

    kind: Lit["select", "ask", "construct"]
    variables: tuple[str, ...] = ()
    rows: tuple[tuple[Term | None, ...], ...] = ()
    boolean: bool | None = None
    triples: tuple[ox.Triple, ...] = ()

    def column(self, name: str) -> list[Term | None]:
        """The values of one variable, in row order."""
        i = self.variables.index(name)
        return [row[i] for row in self.rows]


def parse_binding(text: str) -> tuple[str, Term]:
    """``NAME=VALUE`` from the command line: ``<iri>`` or ``prefix:local`` → IRI, an integer →
    xsd:integer, anything else → a plain string literal."""
    name, sep, value = text.partition("=")
    name = name.strip().lstrip("?$")
    if not sep or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        raise QueryError(f"binding {text!r} is not NAME=VALUE", hint="e.g. --bind broker=pk:Broker or --bind ip=127.0.0.2")
    if value.startswith("<") and value.endswith(">"):
        return name, _iri(value[1:-1], text)
    prefix, colon, local = value.partition(":")
    if colon and prefix in PREFIXES and "/" not in local:
        return name, _iri(PREFIXES[prefix] + local, text)
    if _INTEGER.match(value):
        return name, ox.Literal(value, datatype=ox.NamedNode(str(XSD.integer)))
    return name, ox.Literal(value)


def _iri(value: str, text: str) -> ox.NamedNode:
    try:
        return ox.NamedNode(value)
    except ValueError as exc:
        raise QueryError(f"binding {text!r}: {value!r} is not a valid IRI ({exc})") from None


def run_query(
    plant: PlantGraph | ox.Store,
    query: str,
    bindings: Mapping[str, Term] | None = None,
) -> QueryResult:
    """Run ``query`` on the plant; ``bindings`` pre-bind variables (never spliced into the text)."""
    store = plant.store if isinstance(plant, PlantGraph) else plant
    text = query + values_clause(bindings) if bindings else query
    try:
        answer = store.query(text, prefixes=PREFIXES, use_default_graph_as_union=True)
    except SyntaxError as exc:
        raise _query_error(query, exc) from None
    except OSError as exc:
        raise QueryError(f"the query failed while running: {exc}") from None
    if isinstance(answer, ox.QueryBoolean):
        return QueryResult(kind="ask", boolean=bool(answer))
    if isinstance(answer, ox.QueryTriples):
        return QueryResult(kind="construct", triples=tuple(answer))
    variables = tuple(v.value for v in answer.variables)
    rows = tuple(tuple(sol[v] for v in variables) for sol in answer)
    return QueryResult(kind="select", variables=variables, rows=rows)


def values_clause(bindings: Mapping[str, Term]) -> str:
    """A trailing ``VALUES (?a ?b) { (t1 t2) }`` binding each variable to one term."""
    names = list(bindings)
    for name in names:
        if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
            raise QueryError(f"{name!r} is not a SPARQL variable name")
    terms = []
    for name in names:
        t = bindings[name]
        if not isinstance(t, (ox.NamedNode, ox.Literal)):
            raise QueryError(f"?{name} must be bound to an IRI or a literal, not {type(t).__name__}")
        terms.append(str(t))
    return f"\nVALUES ({' '.join('?' + n for n in names)}) {{ ({' '.join(terms)}) }}"


def _query_error(query: str, exc: SyntaxError) -> QueryError:
    text = str(exc.msg if exc.msg else exc)
    match = _POSITION.match(text)
    if not match:
        return QueryError(f"malformed SPARQL query: {text}", hint="check the query syntax")
    line, column = int(match.group(1)), int(match.group(2))
    problem = text[match.end():]
    lines = query.splitlines() or [""]
    excerpt = lines[line - 1] if 0 < line <= len(lines) else ""
    caret = " " * max(column - 1, 0) + "^"
    if "expected CONSTRUCT" in problem or re.search(r"(?i)^\s*(PREFIX[^\n]*\n\s*)*(INSERT|DELETE|LOAD|CLEAR|DROP|CREATE)\b", query):
        return QueryError("SPARQL updates are not allowed: plantkg queries are read-only",
                          hint="edit the plant's Turtle files instead, then validate and apply")
    return QueryError(
        f"malformed SPARQL query at line {line}, column {column}: {problem}\n    {excerpt}\n    {caret}",
        hint="check the query syntax; pk:, rdf:, rdfs:, owl:, xsd:, sh: and ngsi: are predeclared",
    )
