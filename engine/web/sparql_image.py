"""A copy of the served store for the SPARQL worker processes, sent as little and as seldom as
possible.

``plantkg serve`` keeps one Oxigraph store per loaded plant (a re-read of the files makes a new
one) and rewrites two kinds of graph in place every ``--observe-interval``: the observed state
(``GRAPH_OBSERVED``) and the context brokers' entities (graphs under ``NGSI_GRAPH_BASE``). So an
image has two parts:

- the *base*: the whole store in N-Quads, dumped once per store object (a 10k-resource plant:
  ~25 MB, ~0.15 s to dump, ~0.5 s for a worker to load);
- the *volatile* part: the quads of the rewritten graphs, dumped again when the served snapshot's
  version changes (a few hundred kB at most).

Each part has a key; a worker is sent only the parts whose key differs from what it holds
(engine.web.sparql_pool). Dumps are taken under the caller's guard (the store's read lock), so a
worker never sees a graph half replaced. Loading goes through ``pyoxigraph.parse`` so that blank
node labels stay as they are in the served store (``Store.load`` renames them).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass

import pyoxigraph as ox

from kg.namespaces import GRAPH_OBSERVED, NGSI_GRAPH_BASE

_FORMAT = ox.RdfFormat.N_QUADS


def is_volatile(graph: object) -> bool:
    """Whether ``graph`` is rewritten in place while the server runs (observed state, context)."""
    return isinstance(graph, ox.NamedNode) and (graph.value == GRAPH_OBSERVED
                                                or graph.value.startswith(NGSI_GRAPH_BASE))


@dataclass(frozen=True)
class StoreImage:
    """The served store as N-Quads: ``base`` (key ``base_key``) then ``volatile`` (``volatile_key``)."""

    base_key: int
    base: bytes
    volatile_key: int
    volatile: bytes


class ImageCache:
    """Makes :class:`StoreImage` s of the served store, re-dumping only what changed."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._store: ox.Store | None = None  # held, so a new store never shares an old one's id
        self._version: object = None
        self._image = StoreImage(0, b"", 0, b"")

    def image(self, store: ox.Store, version: object,
              guard: Callable[[], AbstractContextManager[object]]) -> StoreImage:
        """The image of ``store`` as of snapshot ``version``."""
        with self._lock:
            old = self._image
            if store is not self._store:
                with guard():
                    base, volatile = store.dump(format=_FORMAT) or b"", volatile_quads(store)
                self._image = StoreImage(old.base_key + 1, base, old.volatile_key + 1, volatile)
            elif version != self._version:
                with guard():
                    volatile = volatile_quads(store)
                if volatile != old.volatile:
                    self._image = StoreImage(old.base_key, old.base, old.volatile_key + 1, volatile)
            self._store, self._version = store, version
            return self._image


def volatile_quads(store: ox.Store) -> bytes:
    """The quads of the store's volatile graphs, as N-Quads."""
    quads = [q for g in store.named_graphs() if is_volatile(g)
             for q in store.quads_for_pattern(None, None, None, g)]
    return ox.serialize(quads, format=_FORMAT) or b""


def load_base(data: bytes) -> ox.Store:
    """A new store holding a base dump (worker side)."""
    store = ox.Store()
    store.extend(ox.parse(data, format=_FORMAT))
    return store


def replace_volatile(store: ox.Store, data: bytes) -> None:
    """Swap the store's volatile graphs for ``data`` (worker side)."""
    for graph in [g for g in store.named_graphs() if is_volatile(g)]:
        store.remove_graph(graph)
    store.extend(ox.parse(data, format=_FORMAT))
