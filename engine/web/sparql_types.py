"""The values the SPARQL endpoint's parts pass each other: limits, a query's dataset, its answer,
and the typed error that carries an HTTP status.

A module of its own so that the request side (engine.web.sparql_protocol), the pool of worker
processes (engine.web.sparql_pool) and the worker itself (engine.web.sparql_worker) share them
without importing each other. Everything here pickles: answers and errors cross a process boundary.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal as Lit

import pyoxigraph as ox

Term = ox.NamedNode | ox.BlankNode | ox.Literal


class SparqlError(Exception):
    """A query the endpoint will not answer: ``status`` is the HTTP status to send;
    ``retry_after_s``, when set, goes out as a ``Retry-After`` header."""

    def __init__(self, status: int, message: str, hint: str | None = None, *,
                 retry_after_s: int | None = None) -> None:
        super().__init__(message)
        self.status, self.message, self.hint, self.retry_after_s = status, message, hint, retry_after_s

    def __reduce__(self):  # type: ignore[no-untyped-def]  # keyword-only fields survive pickling
        return (_rebuild_error, (self.status, self.message, self.hint, self.retry_after_s))


def _rebuild_error(status: int, message: str, hint: str | None, retry_after_s: int | None) -> SparqlError:
    return SparqlError(status, message, hint, retry_after_s=retry_after_s)


@dataclass(frozen=True)
class Limits:
    """How long a query may run, how many rows (or triples) its answer may hold, how many queries
    may run at once (``workers``: worker processes, the global limit) and how many of them may
    come from one client (``per_client``; a value above ``workers`` leaves only the global limit)."""

    timeout_s: float = 10.0
    max_rows: int = 10_000
    workers: int = 4
    per_client: int = 2

    def __post_init__(self) -> None:
        for name in ("timeout_s", "max_rows", "workers", "per_client"):
            if getattr(self, name) <= 0:
                raise ValueError(f"Limits.{name} must be positive, got {getattr(self, name)!r}")

    @property
    def retry_after_s(self) -> int:
        """Seconds after which a refused client may try again: every running query has ended by
        then (each is stopped at the timeout)."""
        return max(1, math.ceil(self.timeout_s))


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


def timeout_error(timeout_s: float) -> SparqlError:
    """The answer to a query that ran past the endpoint's timeout."""
    return SparqlError(503, f"the query ran longer than the endpoint's timeout of {timeout_s:g} s",
                       hint="make it more selective (bind a variable, add a LIMIT) or ask the operator "
                            "for a longer --query-timeout")
