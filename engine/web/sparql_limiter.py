"""Who may start a SPARQL query now: at most ``per_client`` running queries per client and at
most ``total`` in all (the number of worker processes).

A client is the logged-in user when the request is authenticated, else the remote address
(engine.web.sparql decides). A client over its limit is refused (429) before the global limit is
looked at, so one client sending many slow queries uses at most ``per_client`` workers and the
others stay free for everyone else. Nothing waits here: a refusal is immediate, with a
``Retry-After``; a waiting request would hold a server thread for nothing.

:func:`decide` is the pure rule (tested with cases as data); :class:`QueryLimiter` keeps the
counts under a lock.
"""

from __future__ import annotations

import enum
import threading
from collections.abc import Mapping


class Verdict(enum.Enum):
    ADMIT = "admit"
    CLIENT_LIMIT = "client-limit"  # HTTP 429
    GLOBAL_LIMIT = "global-limit"  # HTTP 503


def decide(running: Mapping[str, int], client: str, *, per_client: int, total: int) -> Verdict:
    """May ``client`` start one more query, with ``running`` queries per client now?"""
    if running.get(client, 0) >= per_client:
        return Verdict.CLIENT_LIMIT
    if sum(running.values()) >= total:
        return Verdict.GLOBAL_LIMIT
    return Verdict.ADMIT


class QueryLimiter:
    """Counts the running queries of each client; :meth:`acquire` admits or refuses one."""

    def __init__(self, *, per_client: int, total: int) -> None:
        if per_client < 1 or total < 1:
            raise ValueError(f"limits must be at least 1 (per_client={per_client}, total={total})")
        self.per_client, self.total = per_client, total
        self._lock = threading.Lock()
        self._running: dict[str, int] = {}

    def acquire(self, client: str) -> Verdict:
        """Admit ``client``'s query (then :meth:`release` it when it ends) or say which limit
        refuses it."""
        with self._lock:
            verdict = decide(self._running, client, per_client=self.per_client, total=self.total)
            if verdict is Verdict.ADMIT:
                self._running[client] = self._running.get(client, 0) + 1
            return verdict

    def release(self, client: str) -> None:
        with self._lock:
            left = self._running.get(client, 0) - 1
            if left < 0:
                raise RuntimeError(f"release without acquire for client {client!r}")
            if left:
                self._running[client] = left
            else:
                del self._running[client]  # a client that went away leaves no entry behind

    def running(self) -> dict[str, int]:
        """A copy of the counts (clients with a running query only)."""
        with self._lock:
            return dict(self._running)
