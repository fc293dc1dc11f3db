"""Evaluating one read-only query on a store: the dataset options, the row limit, the deadline
checked between rows, and parse errors worded for people. Runs inside a worker process
(engine.web.sparql_worker), which is what makes a query stoppable: see engine.web.sparql_pool.

The deadline checked here stops a query that streams its rows (most joins) without losing the
worker. Oxigraph computes an aggregate, an ORDER BY or a DISTINCT over a big join inside
``Store.query`` or before the first row, and offers no way to interrupt that (pyoxigraph 0.5 has
no cancellation); only killing the worker process stops it.
"""

from __future__ import annotations

import re
import time
from collections.abc import Iterable, Iterator
from typing import TypeVar

import pyoxigraph as ox

from engine.web.sparql_types import Answer, Dataset, SparqlError, timeout_error
from kg.errors import QueryError
from kg.namespaces import PREFIXES
from kg.query import run_query

_CHECK_EVERY = 64  # rows between two looks at the clock
T = TypeVar("T")


def evaluate(store: ox.Store, query: str, dataset: Dataset, *, max_rows: int, timeout_s: float,
             deadline: float) -> Answer:
    """Run ``query`` on ``store``; raises :class:`SparqlError` (400 malformed, 403 update,
    413 more than ``max_rows`` results, 503 past ``deadline``, a :func:`time.monotonic` value)."""
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
        raise syntax_error(query, exc) from None
    except (OSError, ValueError) as exc:
        raise SparqlError(500, f"the query failed while running: {exc}") from None
    if isinstance(answer, ox.QueryBoolean):
        return Answer("ask", boolean=bool(answer))
    failure = None
    try:
        result = _collect(answer, max_rows, timeout_s, deadline)
    except SparqlError as exc:
        failure = exc
    # Oxigraph's iterators must be dropped by the thread that made them: drop it here, before an
    # error (whose traceback would hold it) leaves this function.
    del answer
    if failure is not None:
        raise SparqlError(failure.status, failure.message, failure.hint)
    return result


def _collect(answer: ox.QuerySolutions | ox.QueryTriples, max_rows: int, timeout_s: float,
             deadline: float) -> Answer:
    if isinstance(answer, ox.QueryTriples):
        return Answer("graph", triples=tuple(_bounded(answer, max_rows, timeout_s, deadline)))
    variables = tuple(v.value for v in answer.variables)
    rows = tuple(tuple(sol[v] for v in variables) for sol in _bounded(answer, max_rows, timeout_s, deadline))
    return Answer("select", variables=variables, rows=rows)


def _bounded(items: Iterable[T], max_rows: int, timeout_s: float, deadline: float) -> Iterator[T]:
    try:
        for i, item in enumerate(items):
            if i >= max_rows:
                raise SparqlError(413, f"the answer has more than {max_rows} results, the endpoint's limit",
                                  hint="add a LIMIT (and OFFSET to page), or aggregate with COUNT")
            if i % _CHECK_EVERY == 0 and time.monotonic() > deadline:
                raise timeout_error(timeout_s)
            yield item
    except OSError as exc:
        raise SparqlError(500, f"the query failed while running: {exc}") from None


_PROLOGUE = re.compile(r"(?is)^(?:\s+|#[^\n]*\n?|PREFIX\s+[\w.-]*:\s*<[^>]*>|BASE\s*<[^>]*>)*")
_UPDATE_VERBS = re.compile(r"(?i)(INSERT|DELETE|LOAD|CLEAR|DROP|CREATE|ADD|MOVE|COPY|WITH)\b")


def is_update(text: str) -> bool:
    """Whether ``text`` is a SPARQL Update request (its first keyword after the prologue)."""
    return bool(_UPDATE_VERBS.match(text, _PROLOGUE.match(text).end()))  # type: ignore[union-attr]


def syntax_error(query: str, exc: SyntaxError) -> SparqlError:
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
