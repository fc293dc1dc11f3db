"""The SPARQL 1.1 Protocol's query operation, without the web framework: admit, run, serialise.

- :class:`QueryRunner` admits a query (engine.web.sparql_limiter: at most ``Limits.per_client``
  running queries per client, 429; at most ``Limits.workers`` in all, 503), then runs it in a
  worker process (engine.web.sparql_pool) on a copy of the store (engine.web.sparql_image), with
  a deadline and a result-size limit. A query past its deadline is stopped for real: a streaming
  one by the worker between rows, one that computes before its first row (an aggregate or ORDER
  BY over a huge join) by killing the worker, whose slot is free again at once. Updates are
  refused (:class:`SparqlError` 403).
- :func:`negotiate` picks a result format from the Accept header; :func:`serialize` writes it:
  SPARQL JSON, XML, CSV, TSV for SELECT/ASK, Turtle, JSON-LD, N-Triples, RDF/XML for CONSTRUCT and
  DESCRIBE (W3C "SPARQL 1.1 Query Results JSON/XML/CSV and TSV Formats").
"""

from __future__ import annotations

import csv
import io
import json
from collections.abc import Callable
from contextlib import AbstractContextManager, nullcontext
from xml.sax.saxutils import escape, quoteattr

import pyoxigraph as ox
from werkzeug.datastructures import MIMEAccept

from engine.web.sparql_eval import is_update
from engine.web.sparql_image import ImageCache
from engine.web.sparql_limiter import QueryLimiter, Verdict
from engine.web.sparql_pool import WorkerPool
from engine.web.sparql_types import Answer, Dataset, Limits, SparqlError, Term, timeout_error
from kg.namespaces import PREFIXES, XSD

__all__ = ["Answer", "Dataset", "Limits", "QueryRunner", "SparqlError", "Term", "is_update", "negotiate",
           "offered_types", "serialize", "timeout_error"]

_XSD_STRING = str(XSD.string)

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


class QueryRunner:
    """Admits queries per client and runs them in worker processes with the deadline of ``limits``."""

    def __init__(self, limits: Limits) -> None:
        self.limits = limits
        self.limiter = QueryLimiter(per_client=limits.per_client, total=limits.workers)
        self.pool = WorkerPool(limits.workers)
        self._images = ImageCache()

    def close(self) -> None:
        """Stop every worker process (the server is shutting down)."""
        self.pool.close()

    def execute(self, store: ox.Store, query: str, dataset: Dataset = Dataset(),
                guard: Callable[[], AbstractContextManager[object]] = nullcontext, *,
                version: object = None, client: str = "anonymous") -> Answer:
        """Run ``query`` for ``client`` on ``store`` as of snapshot ``version`` (``guard``, e.g. a
        read lock, is held only while the store is copied); raises :class:`SparqlError` (400
        malformed, 403 update, 413 too large, 429 ``client`` runs too many queries, 503 timeout or
        too many queries in all)."""
        verdict = self.limiter.acquire(client)
        if verdict is not Verdict.ADMIT:
            raise refusal(verdict, client, self.limits)
        try:
            image = self._images.image(store, version, guard)
            return self.pool.run(image, query, dataset, max_rows=self.limits.max_rows,
                                 timeout_s=self.limits.timeout_s)
        finally:
            self.limiter.release(client)


def refusal(verdict: Verdict, client: str, limits: Limits) -> SparqlError:
    """The error for a query the limiter refused (429 over the client's limit, 503 over the total)."""
    wait = limits.retry_after_s
    if verdict is Verdict.CLIENT_LIMIT:
        return SparqlError(
            429, f"too many queries at once from {client}: the endpoint runs at most {limits.per_client} "
                 "per client at a time (plantkg serve --max-client-queries)",
            f"wait until one of your queries has answered (each ends within {limits.timeout_s:g} s, the "
            f"query timeout) and retry after {wait} s; send queries one after another, not in parallel",
            retry_after_s=wait)
    return SparqlError(
        503, f"the endpoint is busy: {limits.workers} queries are running, its limit "
             "(plantkg serve --max-queries)",
        f"retry after {wait} s", retry_after_s=wait)


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
