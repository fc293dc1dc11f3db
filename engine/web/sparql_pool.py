"""A pool of SPARQL worker processes, so that a query past its timeout is really stopped.

Why processes: pyoxigraph (0.5) evaluates a query with the GIL released but cannot be
interrupted. Measured on the robot cell (1,177 quads), ``SELECT (COUNT(*) AS ?n) WHERE { ?a ?b ?c
. ?d ?e ?f . ?g a owl:Class }`` spends 4.1 s inside ``Store.query`` before its first (only) row, and
a join of three triple patterns would take hours; a deadline checked between rows (the endpoint's
first design) never gets a look in. A thread running such a query cannot be stopped: it held a
slot of the pool and the store's read lock until it finished, so three of them made the endpoint
answer 503 to everything. A process can be killed: on timeout the worker gets SIGKILL, is reaped,
and its slot is free at once; the next query that needs a worker starts a fresh one (~0.3 s).

Each worker holds a copy of the store (engine.web.sparql_image: the base once per loaded plant,
the observed and context graphs again when they change), so a query never holds the server's
store lock while it runs. Workers start on first need and stay idle for the next query; at most
``size`` exist. The pool does not decide who may query: engine.web.sparql_limiter admits at most
``size`` queries at once, so a free worker (or room for a new one) is always there.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
import weakref
from dataclasses import dataclass
from multiprocessing.connection import Connection

from engine.web.sparql_image import StoreImage
from engine.web.sparql_types import Answer, Dataset, SparqlError, timeout_error
from engine.web.sparql_worker import Job

#: Seconds a worker may take to start (import pyoxigraph, say ready) before it counts as broken.
START_TIMEOUT_S = 60.0
#: Extra seconds the worker gets past the timeout to answer 503 itself (a streaming query) before
#: it is killed.
GRACE_S = 0.5


@dataclass
class _Worker:
    proc: subprocess.Popen[bytes]
    conn: Connection
    base_key: int = 0  # the image parts it holds (0: none; image keys start at 1)
    volatile_key: int = 0


class WorkerPool:
    """At most ``size`` worker processes; :meth:`run` one query on one of them."""

    def __init__(self, size: int) -> None:
        self.size = size
        self._lock = threading.Lock()
        self._idle: list[_Worker] = []
        self._all: list[_Worker] = []  # idle and busy; shared with the finalizer
        self._closed = False
        self._starting = 0  # workers being spawned
        weakref.finalize(self, _kill_all, self._all)

    def pids(self) -> list[int]:
        """The worker processes alive now (for tests and diagnostics)."""
        with self._lock:
            return [w.proc.pid for w in self._all]

    def run(self, image: StoreImage, query: str, dataset: Dataset, *, max_rows: int, timeout_s: float) -> Answer:
        """Answer ``query`` on ``image``; raises :class:`SparqlError` (the query's own errors,
        503 past ``timeout_s`` — the worker is then killed — 500 a worker that died)."""
        worker = self._checkout()
        fresh = worker.base_key == image.base_key
        job = Job(query, dataset, max_rows, timeout_s,
                  base=None if fresh else image.base,
                  volatile=None if fresh and worker.volatile_key == image.volatile_key else image.volatile)
        try:
            worker.conn.send(job)
            if not worker.conn.poll(timeout_s + GRACE_S):
                self._discard(worker)
                raise timeout_error(timeout_s)
            outcome = worker.conn.recv()
        except (EOFError, OSError) as exc:
            self._discard(worker)
            raise SparqlError(500, f"the query's worker process ended unexpectedly ({_exit_text(worker, exc)})",
                              "retry; if it happens again the query may need more memory than the "
                              "machine has: make it more selective") from None
        # A 500 from the worker means its copy of the plant is suspect: it loads it again next time.
        self._checkin(worker, None if isinstance(outcome, SparqlError) and outcome.status == 500 else image)
        if isinstance(outcome, SparqlError):
            raise outcome
        return outcome

    def close(self) -> None:
        """Kill and reap every worker; later queries get 503."""
        with self._lock:
            self._closed = True
            self._idle.clear()
        _kill_all(self._all)

    # ----------------------------------------------------------------------------- internals

    def _checkout(self) -> _Worker:
        with self._lock:
            if self._closed:
                raise SparqlError(503, "the server is shutting down")
            while self._idle:
                worker = self._idle.pop()
                if worker.proc.poll() is None:
                    return worker
                self._all.remove(worker)  # died while idle (OOM killer, a stray kill): replace it
                worker.conn.close()
            if len(self._all) + self._starting >= self.size:  # the limiter keeps this from happening
                raise SparqlError(503, f"all {self.size} query workers are busy", "retry in a moment")
            self._starting += 1
        try:
            worker = _spawn()
        finally:
            with self._lock:
                self._starting -= 1
        with self._lock:
            if not self._closed:
                self._all.append(worker)
                return worker
        _kill_all([worker])
        raise SparqlError(503, "the server is shutting down")

    def _checkin(self, worker: _Worker, image: StoreImage | None) -> None:
        """Back to the idle workers, holding ``image`` (None: nothing it can be trusted with)."""
        worker.base_key, worker.volatile_key = (image.base_key, image.volatile_key) if image else (0, 0)
        with self._lock:
            if not self._closed:
                self._idle.append(worker)

    def _discard(self, worker: _Worker) -> None:
        _kill_all([worker])
        with self._lock:
            if worker in self._all:
                self._all.remove(worker)


def _spawn() -> _Worker:
    """Start a worker and wait for its hello; raises :class:`SparqlError` 503 if it does not come."""
    ours, theirs = socket.socketpair()
    try:
        proc = subprocess.Popen(  # noqa: S603 - argv list, no shell
            [sys.executable, "-m", "engine.web.sparql_worker", str(theirs.fileno())],
            pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL, close_fds=True)
    except OSError as exc:
        ours.close()
        raise SparqlError(503, f"cannot start a SPARQL worker process: {exc}", "see the server's log") from None
    finally:
        theirs.close()
    worker = _Worker(proc, Connection(ours.detach()))
    try:
        if worker.conn.poll(START_TIMEOUT_S):
            hello = worker.conn.recv()
            if isinstance(hello, tuple) and hello[:1] == ("ready",):
                return worker
    except (EOFError, OSError):
        pass
    _kill_all([worker])
    raise SparqlError(503, f"a SPARQL worker process did not start (exit code {proc.returncode})",
                      "see the server's log for its error")


def _kill_all(workers: list[_Worker]) -> None:
    """SIGKILL and reap ``workers`` (already gone ones too); close their connections."""
    for worker in list(workers):
        try:
            worker.proc.kill()
        except OSError:
            pass
    for worker in list(workers):
        try:
            worker.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:  # uninterruptible sleep; the kernel finishes it
            pass
        worker.conn.close()


def _exit_text(worker: _Worker, exc: BaseException) -> str:
    code = worker.proc.poll()
    if code is None:
        return f"{type(exc).__name__}: {exc}"
    return f"killed by signal {-code}" if code < 0 else f"exit code {code}"
