"""Query answers as small tables a notebook shows: plain values, short names, HTML and text.

A :class:`kg.query.QueryResult` holds RDF terms; a person exploring a plant wants ``mm:robot-a1``
rather than a full IRI and the number 1883 rather than a typed literal. :func:`table` turns a
SELECT answer into a :class:`Table` of plain Python values (IRIs shortened with the plant's
prefixes, integers, decimals and booleans converted, unbound cells ``None``). A ``Table`` renders
itself in Jupyter (``_repr_html_``, every cell HTML-escaped) and as aligned text (``str``), so a
notebook cell needs no code of its own to show an answer, and ``column`` hands a plot its values.
:func:`select` runs a query on a loaded plant and returns its table in one call.
"""

from __future__ import annotations

import html
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from decimal import Decimal

import pyoxigraph as ox

from kg.errors import QueryError
from kg.load import PlantGraph
from kg.query import QueryResult, Term, run_query
from kg.render import Compactor

Value = str | int | float | bool | None

_XSD = "http://www.w3.org/2001/XMLSchema#"
_INTEGERS = {f"{_XSD}{t}" for t in ("integer", "int", "long", "short", "byte", "nonNegativeInteger",
                                     "positiveInteger", "unsignedInt", "unsignedShort", "unsignedLong")}
_DECIMALS = {f"{_XSD}{t}" for t in ("decimal", "double", "float")}


@dataclass(frozen=True)
class Table:
    """Named columns of plain values; shows itself as HTML in Jupyter and as text elsewhere."""

    headers: tuple[str, ...]
    rows: tuple[tuple[Value, ...], ...]

    def column(self, name: str) -> list[Value]:
        """The values of one column, in row order."""
        if name not in self.headers:
            raise QueryError(f"the table has no column {name!r}",
                             hint=f"its columns are: {', '.join(self.headers)}")
        i = self.headers.index(name)
        return [row[i] for row in self.rows]

    def records(self) -> list[dict[str, Value]]:
        """One dict per row (column name → value)."""
        return [dict(zip(self.headers, row)) for row in self.rows]

    def _repr_html_(self) -> str:
        head = "".join(f"<th>{html.escape(h)}</th>" for h in self.headers)
        body = "".join("<tr>" + "".join(f"<td>{html.escape(_text(v))}</td>" for v in row) + "</tr>"
                       for row in self.rows)
        return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"

    def __str__(self) -> str:
        cells = [[_text(v) for v in row] for row in self.rows]
        widths = [max([len(h), *(len(r[i]) for r in cells)]) for i, h in enumerate(self.headers)]
        lines = ["  ".join(h.ljust(w) for h, w in zip(self.headers, widths)).rstrip(),
                 "  ".join("─" * w for w in widths)]
        lines += ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in cells]
        lines.append(f"({len(cells)} row{'s' * (len(cells) != 1)})")
        return "\n".join(lines)

    def _repr_pretty_(self, printer: object, cycle: bool) -> None:  # IPython's text form
        printer.text(str(self))  # type: ignore[attr-defined]


def table(result: QueryResult, prefixes: Mapping[str, str] | None = None) -> Table:
    """A SELECT answer as a :class:`Table`; IRIs shortened with ``prefixes`` and the usual ones."""
    if result.kind != "select":
        raise QueryError(f"only a SELECT answer is a table, not {result.kind.upper()}",
                         hint="write the query as SELECT ?a ?b WHERE { ... }")
    short = Compactor(prefixes)
    return Table(tuple(result.variables),
                 tuple(tuple(value(t, short) for t in row) for row in result.rows))


def select(plant: PlantGraph, query: str, bindings: Mapping[str, Term] | None = None) -> Table:
    """Run a SELECT ``query`` on ``plant`` (``bindings`` as in :func:`kg.query.run_query`) and
    return its answer as a :class:`Table` with the plant's own prefixes."""
    return table(run_query(plant, query, bindings), plant.prefixes)


def from_records(records: Iterable[Mapping[str, Value]], headers: Iterable[str]) -> Table:
    """A :class:`Table` from dicts (missing keys are ``None``), columns in ``headers`` order."""
    names = tuple(headers)
    return Table(names, tuple(tuple(r.get(h) for h in names) for r in records))


def value(term: Term | None, short: Compactor | None = None) -> Value:
    """One RDF term as a plain value: a short name for an IRI, a number or bool for a typed literal."""
    if term is None:
        return None
    if isinstance(term, ox.NamedNode):
        return (short or Compactor()).iri(term.value)
    if isinstance(term, ox.BlankNode):
        return f"_:{term.value}"
    datatype = term.datatype.value
    try:
        if datatype in _INTEGERS:
            return int(term.value)
        if datatype in _DECIMALS:
            return float(Decimal(term.value)) if datatype.endswith("decimal") else float(term.value)
    except ValueError:  # an ill-typed literal stays text
        return term.value
    if datatype == f"{_XSD}boolean" and term.value in ("true", "false", "1", "0"):
        return term.value in ("true", "1")
    return term.value


def _text(v: Value) -> str:
    if v is None:
        return ""
    if isinstance(v, bool):
        return "true" if v else "false"
    return str(v)
