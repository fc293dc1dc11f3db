"""The SPARQL 1.1 Protocol's query operation, without the web framework: run, limit, serialise.

- :func:`execute` runs a read-only query on a store in a worker thread with a deadline and a
  result-size limit. Rows are read lazily, so a query that streams (most joins) is stopped when its
  time is up; one that must compute everything before its first row (ORDER BY over a huge join) is
  abandoned after the deadline — its answer is refused on time, its thread finishes in the
  background (a small pool bounds how many can). Updates are refused (:class:`SparqlError` 403).
- :func:`negotiate` picks a result format from the Accept header; :func:`serialize` writes it:
  SPARQL JSON, XML, CSV, TSV for SELECT/ASK, Turtle, JSON-LD, N-Triples, RDF/XML for CONSTRUCT and
  DESCRIBE (W3C "SPARQL 1.1 Query Results JSON/XML/CSV and TSV Formats").
"""

from __future__ import annotations

import csv
import io
import json
import re
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass
from typing import Any, Literal as Lit
from xml.sax.saxutils import escape, quoteattr

import pyoxigraph as ox
from werkzeug.datastructures import MIMEAccept

from kg.errors import QueryError
from kg.namespaces import PREFIXES, XSD
from kg.query import run_query

Term = ox.NamedNode | ox.BlankNode | ox.Literal
_XSD_STRING = str(XSD.string)
_CHECK_EVERY = 64  # rows between two looks at the clock

#: Result media types → format name, for SELECT/ASK and for CONSTRUCT/DESCRIBE.
SOLUTION_TYPES: dict[str, str] = {
    "application/sparql-results+json": "json",
    "application/json": "json",
    "application/sparql-results+xml": "xml",
    "application/xml": "xml",
    "text/csv": "csv",
    "text/tab-separated-values": "tsv",
}
GRAPH_TYPES: dict[str, ox.RdfFormat] = {
    "text/turtle": ox.RdfFormat.TURTLE,
    "application/ld+json": ox.RdfFormat.JSON_LD,
    "application/n-triples": ox.RdfFormat.N_TRIPLES,
    "application/rdf+xml": ox.RdfFormat.RDF_XML,
}


class SparqlError(Exception):
    """A query the endpoint will not answer: ``status`` is the HTTP status to send."""

    def __init__(self, status: int, message: str, hint: str | None = None) -> None:
        super().__init__(message)
        self.status, self.message, self.hint = status, message, hint


@dataclass(frozen=True)
class Limits:
    """How long a query may run and how many rows (or triples) its answer may hold."""

    timeout_s: float = 10.0
    max_rows: int = 10_000
    workers: int = 4


@dataclass(frozen=True)
class Answer:
    """A finished query: ``kind`` says which of the other fields are set."""

    kind: Lit["select", "ask", "graph"]
    variables: tuple[str, ...] = ()
    rows: tuple[tuple[Term | None, ...], ...] = ()
    boolean: bool | None = None
    triples: tuple[ox.Triple, ...] = ()


@dataclass(frozen=True)
class Dataset:
    """The protocol's ``default-graph-uri`` / ``named-graph-uri``; empty: the store's union."""

    default_graphs: tuple[str, ...] = ()
    named_graphs: tuple[str, ...] = ()


class QueryRunner:
    """Runs queries in a bounded pool of threads, each with the deadline of ``limits``."""

    def __init__(self, limits: Limits) -> None:
        self.limits = limits
        self._pool = ThreadPoolExecutor(max_workers=limits.workers, thread_name_prefix="sparql")
        self._slots = threading.BoundedSemaphore(limits.workers * 2)

    def close(self) -> None:
        self._pool.shutdown(wait=False, cancel_futures=True)

    def execute(self, store: ox.Store, query: str, dataset: Dataset = Dataset(),
                guard: Callable[[], AbstractContextManager[object]] = nullcontext) -> Answer:
        """Run ``query`` (inside ``guard``, e.g. a read lock); raises :class:`SparqlError`
        (400 malformed, 403 update, 413 too large, 503 timeout or too many queries running)."""
        if not self._slots.acquire(blocking=False):
            raise SparqlError(503, "too many queries are running; try again in a moment")
        cancel = threading.Event()
        future = self._pool.submit(_guarded, guard, store, query, dataset, self.limits, cancel)
        future.add_done_callback(lambda _f: self._slots.release())
        try:
            return future.result(timeout=self.limits.timeout_s)
        except FutureTimeout:
            cancel.set()
            raise _timeout(self.limits) from None


def _timeout(limits: Limits) -> SparqlError:
    return SparqlError(503, f"the query ran longer than the endpoint's timeout of {limits.timeout_s:g} s",
                       hint="make it more selective (bind a variable, add a LIMIT) or ask the operator "
                            "for a longer --query-timeout")


def _guarded(guard: Callable[[], AbstractContextManager[object]], *args: Any) -> Answer:
    with guard():
        return _run(*args)


def _run(store: ox.Store, query: str, dataset: Dataset, limits: Limits, cancel: threading.Event) -> Answer:
    deadline = time.monotonic() + limits.timeout_s
    options: dict[str, object] = {"prefixes": PREFIXES}
    if dataset.default_graphs:
        options["default_graph"] = [ox.NamedNode(g) for g in dataset.default_graphs]
    else:
        options["use_default_graph_as_union"] = True
    if dataset.named_graphs:
        options["named_graphs"] = [ox.NamedNode(g) for g in dataset.named_graphs]
    try:
        answer = store.query(query, **options)  # type: ignore[arg-type]
    except SyntaxError as exc:
        raise _syntax_error(query, exc) from None
    except (OSError, ValueError) as exc:
        raise SparqlError(500, f"the query failed while running: {exc}") from None
    if isinstance(answer, ox.QueryBoolean):
        return Answer("ask", boolean=bool(answer))
    failure = None
    try:
        result = _collect(answer, limits, deadline, cancel)
    except SparqlError as exc:
        failure = (exc.status, exc.message, exc.hint)
    # Oxigraph's iterators must be dropped by the thread that made them: drop it here, before an
    # error (whose traceback would hold it) travels to the request's thread.
    del answer
    if failure:
        raise SparqlError(*failure)
    return result


def _collect(answer: ox.QuerySolutions | ox.QueryTriples, limits: Limits, deadline: float,
             cancel: threading.Event) -> Answer:
    if isinstance(answer, ox.QueryTriples):
        return Answer("graph", triples=tuple(_bounded(answer, limits, deadline, cancel)))
    variables = tuple(v.value for v in answer.variables)
    rows = tuple(tuple(sol[v] for v in variables) for sol in _bounded(answer, limits, deadline, cancel))
    return Answer("select", variables=variables, rows=rows)


def _bounded(items, limits: Limits, deadline: float, cancel: threading.Event):  # type: ignore[no-untyped-def]
    try:
        for i, item in enumerate(items):
            if i >= limits.max_rows:
                raise SparqlError(413, f"the answer has more than {limits.max_rows} results, the endpoint's limit",
                                  hint="add a LIMIT (and OFFSET to page), or aggregate with COUNT")
            if i % _CHECK_EVERY == 0 and (cancel.is_set() or time.monotonic() > deadline):
                raise _timeout(limits)
            yield item
    except OSError as exc:
        raise SparqlError(500, f"the query failed while running: {exc}") from None


_PROLOGUE = re.compile(r"(?is)^(?:\s+|#[^\n]*\n?|PREFIX\s+[\w.-]*:\s*<[^>]*>|BASE\s*<[^>]*>)*")
_UPDATE_VERBS = re.compile(r"(?i)(INSERT|DELETE|LOAD|CLEAR|DROP|CREATE|ADD|MOVE|COPY|WITH)\b")


def is_update(text: str) -> bool:
    """Whether ``text`` is a SPARQL Update request (its first keyword after the prologue)."""
    return bool(_UPDATE_VERBS.match(text, _PROLOGUE.match(text).end()))  # type: ignore[union-attr]


def _syntax_error(query: str, exc: SyntaxError) -> SparqlError:
    """An update is refused (403); else kg.query words the parse error (position and caret)."""
    if is_update(query):
        return SparqlError(403, "SPARQL updates are not allowed: this endpoint is read-only",
                           "edit the plant's Turtle files instead; the server re-reads them")
    try:
        run_query(ox.Store(), query)
    except QueryError as error:
        if "updates are not allowed" not in error.message:
            return SparqlError(400, error.message, error.hint)
    return SparqlError(400, f"malformed SPARQL query: {exc.msg or exc}", "check the query syntax")


# --------------------------------------------------------------------------- content negotiation

def negotiate(accept: MIMEAccept, kind: str) -> tuple[str, str] | None:
    """(media type, format) for an answer of ``kind`` under ``accept``; None: nothing acceptable.

    No Accept header, or ``*/*``: SPARQL JSON for solutions, Turtle for graphs."""
    offered = offered_types(kind)
    if not accept or not accept.values():
        chosen: str | None = offered[0]
    else:
        chosen = accept.best_match(offered)
    if chosen is None:
        return None
    return chosen, (GRAPH_TYPES[chosen].name if kind == "graph" else SOLUTION_TYPES[chosen])


def offered_types(kind: str) -> list[str]:
    """Media types an answer of ``kind`` can be written in (CSV/TSV have no boolean form)."""
    if kind == "graph":
        return list(GRAPH_TYPES)
    if kind == "ask":
        return [t for t, fmt in SOLUTION_TYPES.items() if fmt in ("json", "xml")]
    return list(SOLUTION_TYPES)


# ----------------------------------------------------------------------------------- serialisers

def serialize(answer: Answer, media_type: str) -> bytes:
    """The answer in ``media_type`` (one :func:`negotiate` chose)."""
    if answer.kind == "graph":
        return ox.serialize(answer.triples, format=GRAPH_TYPES[media_type], prefixes=PREFIXES) or b""
    fmt = SOLUTION_TYPES[media_type]
    if fmt == "json":
        return results_json(answer).encode()
    if fmt == "xml":
        return results_xml(answer).encode()
    return results_delimited(answer, tab=fmt == "tsv").encode()


def json_term(term: Term) -> dict[str, str]:
    """One RDF term as SPARQL JSON results write it."""
    if isinstance(term, ox.NamedNode):
        return {"type": "uri", "value": term.value}
    if isinstance(term, ox.BlankNode):
        return {"type": "bnode", "value": term.value}
    if isinstance(term, ox.Literal):
        out = {"type": "literal", "value": term.value}
        if term.language:
            out["xml:lang"] = term.language
        elif term.datatype.value != _XSD_STRING:
            out["datatype"] = term.datatype.value
        return out
    return {"type": "literal", "value": str(term)}  # RDF-star triple terms: their N-Triples text


def results_json(answer: Answer) -> str:
    if answer.kind == "ask":
        return json.dumps({"head": {}, "boolean": answer.boolean})
    bindings = [{v: json_term(t) for v, t in zip(answer.variables, row) if t is not None}
                for row in answer.rows]
    return json.dumps({"head": {"vars": list(answer.variables)}, "results": {"bindings": bindings}},
                      ensure_ascii=False)


def _xml_term(term: Term) -> str:
    if isinstance(term, ox.NamedNode):
        return f"<uri>{escape(term.value)}</uri>"
    if isinstance(term, ox.BlankNode):
        return f"<bnode>{escape(term.value)}</bnode>"
    if isinstance(term, ox.Literal):
        if term.language:
            return f"<literal xml:lang={quoteattr(term.language)}>{escape(term.value)}</literal>"
        if term.datatype.value != _XSD_STRING:
            return f"<literal datatype={quoteattr(term.datatype.value)}>{escape(term.value)}</literal>"
        return f"<literal>{escape(term.value)}</literal>"
    return f"<literal>{escape(str(term))}</literal>"


def results_xml(answer: Answer) -> str:
    out = ['<?xml version="1.0"?>', '<sparql xmlns="http://www.w3.org/2005/sparql-results#">', "<head>"]
    out += [f"<variable name={quoteattr(v)}/>" for v in answer.variables]
    out.append("</head>")
    if answer.kind == "ask":
        out.append(f"<boolean>{'true' if answer.boolean else 'false'}</boolean>")
    else:
        out.append("<results>")
        for row in answer.rows:
            cells = "".join(f"<binding name={quoteattr(v)}>{_xml_term(t)}</binding>"
                            for v, t in zip(answer.variables, row) if t is not None)
            out.append(f"<result>{cells}</result>")
        out.append("</results>")
    out.append("</sparql>")
    return "\n".join(out)


def results_delimited(answer: Answer, *, tab: bool) -> str:
    """CSV (plain values) or TSV (terms in N-Triples/Turtle syntax), as the W3C note says."""
    if tab:
        lines = ["\t".join("?" + v for v in answer.variables)]
        lines += ["\t".join("" if t is None else str(t) for t in row) for row in answer.rows]
        return "\n".join(lines) + "\n"
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\r\n")
    writer.writerow(answer.variables)
    for row in answer.rows:
        writer.writerow(["" if t is None else (t.value if hasattr(t, "value") else str(t)) for t in row])
    return buf.getvalue()
