"""A SPARQL worker process: ``python -m engine.web.sparql_worker FD``.

It holds a copy of the served store (engine.web.sparql_image) and answers one :class:`Job` at a
time on the connection ``FD`` (a socket its parent, engine.web.sparql_pool, made and passed on):
first ``("ready", pid)``, then for each job an :class:`~engine.web.sparql_types.Answer` or a
:class:`~engine.web.sparql_types.SparqlError`. The parent kills it when a query passes its
timeout; that is the point of running queries here rather than in a thread of the server.

It ends when the connection closes, and by itself when its parent dies (checked every second),
so a ``kill -9`` of ``plantkg serve`` leaves no evaluating orphan. Ctrl-C in a terminal is its
parent's business: it ignores SIGINT and is stopped by its parent.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from dataclasses import dataclass
from multiprocessing.connection import Connection

import pyoxigraph as ox

from engine.web.sparql_eval import evaluate
from engine.web.sparql_image import load_base, replace_volatile
from engine.web.sparql_types import Answer, Dataset, SparqlError

_PARENT_CHECK_S = 1.0


@dataclass(frozen=True)
class Job:
    """One query, and the parts of the store image the worker lacks (None: it has them)."""

    query: str
    dataset: Dataset
    max_rows: int
    timeout_s: float
    base: bytes | None = None
    volatile: bytes | None = None


def handle(store: ox.Store | None, job: Job) -> tuple[ox.Store | None, Answer | SparqlError]:
    """Bring ``store`` up to date with ``job``'s image parts, then run its query."""
    deadline = time.monotonic() + job.timeout_s
    try:
        if job.base is not None:
            store = None  # free the old copy before the new one is built
            store = load_base(job.base)
        if store is None:
            return None, SparqlError(500, "the query worker has no copy of the plant yet",
                                     "retry; if it persists, restart plantkg serve")
        if job.volatile is not None:
            replace_volatile(store, job.volatile)
        return store, evaluate(store, job.query, job.dataset, max_rows=job.max_rows,
                               timeout_s=job.timeout_s, deadline=deadline)
    except SparqlError as exc:
        return store, exc
    except (OSError, SyntaxError, ValueError) as exc:  # an image that did not load
        return None, SparqlError(500, f"the query worker could not load the plant: {exc}",
                                 "retry; if it persists, restart plantkg serve")


def _watch_parent(parent: int) -> None:
    stop = threading.Event()
    while not stop.wait(_PARENT_CHECK_S):
        if os.getppid() != parent:
            os._exit(0)


def main(argv: list[str]) -> int:
    if len(argv) != 1 or not argv[0].isdigit():
        print("usage: python -m engine.web.sparql_worker FD (started by plantkg serve)", file=sys.stderr)
        return 2
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_watch_parent, args=(os.getppid(),), name="parent-watch", daemon=True).start()
    conn = Connection(int(argv[0]))
    conn.send(("ready", os.getpid()))
    store: ox.Store | None = None
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):
            return 0
        store, outcome = handle(store, job)
        try:
            conn.send(outcome)
        except OSError:
            return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
