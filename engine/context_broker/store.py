"""The durable context: an on-disk Oxigraph store (RDF, one named graph per tenant) with an
in-memory index of the entities for reads.

- Every write runs under one write lock: it looks the entities up in the index, computes the new
  ones (pure functions of :mod:`.entities`; a refusal raises before anything is written), writes
  the difference of their triples as ONE SPARQL Update (one RocksDB transaction, in its
  write-ahead log before ``update`` returns, so an acknowledged write survives kill -9), then
  swaps the new immutable :class:`Entity` objects into the index and tells every
  :class:`ChangeListener`, in write order, before the caller answers.
- Reads take no lock: the index holds immutable entities and a write replaces them whole, so a
  reader sees an entity before or after a write, never half of one.
- At start the index is rebuilt from the store (:func:`.rdf.entities_from_quads`).
- ``data_dir/context.lock`` (``flock``) keeps a second process off the same folder.
"""

from __future__ import annotations

import fcntl
import logging
import os
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyoxigraph as ox

from engine.context_broker import rdf
from engine.context_broker.contract import ChangeListener, EntityChange, NgsiError, Tenant, not_found
from engine.context_broker.entities import Entity

log = logging.getLogger(__name__)
Key = tuple[str, str]
LOCK_FILE = "context.lock"
STORE_DIR = "oxigraph"


class StoreLocked(RuntimeError):
    """Another process holds the data folder."""


@dataclass(frozen=True)
class ReadScope:
    """The tenants a read covers: one service and its ``Fiware-ServicePath`` list, each path
    exact or with its descendants (``/a/#``; no header means ``/#``)."""

    service: str
    paths: tuple[tuple[str, bool], ...] = (("/", True),)

    def covers(self, tenant: Tenant) -> bool:
        if tenant.service != self.service:
            return False
        for path, recursive in self.paths:
            if tenant.service_path == path:
                return True
            if recursive and (path == "/" or tenant.service_path.startswith(path + "/")):
                return True
        return False


@dataclass
class _TenantIndex:
    entities: dict[Key, Entity] = field(default_factory=dict)
    nodes: dict[Key, str] = field(default_factory=dict)
    heads: dict[Key, frozenset[rdf.Triple]] = field(default_factory=dict)
    attr_triples: dict[Key, dict[str, tuple[Any, frozenset[rdf.Triple]]]] = field(default_factory=dict)
    by_id: dict[str, dict[str, Entity]] = field(default_factory=dict)


def too_many(entity_id: str) -> NgsiError:
    return NgsiError(409, "TooManyResults", f"More than one matching entity (id {entity_id!r} has "
                                            "several types). Please refine your query with type")


class Transaction:
    """The entities one write request touches, looked up and replaced under the write lock."""

    def __init__(self, store: ContextStore, tenant: Tenant, now: float) -> None:
        self.store, self.tenant, self.now = store, tenant, now
        self.idx = store._tenants.get(tenant) or _TenantIndex()
        self.pending: dict[Key, Entity | None] = {}
        self.changes: list[EntityChange] = []

    def candidates(self, entity_id: str) -> dict[str, Entity]:
        found = dict(self.idx.by_id.get(entity_id, {}))
        for (pid, ptype), entity in self.pending.items():
            if pid == entity_id:
                if entity is None:
                    found.pop(ptype, None)
                else:
                    found[ptype] = entity
        return found

    def find(self, entity_id: str, entity_type: str | None) -> Entity | None:
        """The entity, None when absent; 409 when ``entity_type`` is None and the id is ambiguous."""
        found = self.candidates(entity_id)
        if entity_type is not None:
            return found.get(entity_type)
        if len(found) > 1:
            raise too_many(entity_id)
        return next(iter(found.values()), None)

    def get(self, entity_id: str, entity_type: str | None) -> Entity:
        entity = self.find(entity_id, entity_type)
        if entity is None:
            raise not_found()
        return entity

    def put(self, old: Entity | None, new: Entity | None, changed: Iterable[str], *,
            forced: bool = False) -> None:
        current = new if new is not None else old
        assert current is not None
        self.pending[(current.id, current.type)] = new
        self.changes.append(EntityChange(self.tenant, current.normalized, frozenset(changed),
                                         created=old is None, deleted=new is None, forced=forced))


class ContextStore:
    """``ContextStore(data_dir)`` durable; ``ContextStore(None)`` in memory (tests)."""

    def __init__(self, data_dir: Path | str | None = None) -> None:
        self._lock_fd: int | None = None
        if data_dir is None:
            self._store = ox.Store()
        else:
            root = Path(data_dir)
            root.mkdir(parents=True, exist_ok=True)
            self._lock_fd = _lock(root / LOCK_FILE)
            self._store = ox.Store(str(root / STORE_DIR))
        self._write_lock = threading.Lock()
        self._listeners: list[ChangeListener] = []
        self._tenants: dict[Tenant, _TenantIndex] = {}
        self._load()

    def _load(self) -> None:
        for graph in self._store.named_graphs():
            if not isinstance(graph, ox.NamedNode):
                continue
            tenant = rdf.tenant_of_graph(graph.value)
            if tenant is None:
                continue
            idx = _TenantIndex()
            quads = self._store.quads_for_pattern(None, None, None, graph)
            for entity, node in rdf.entities_from_quads(quads, tenant.service_path):
                _index(idx, entity, node)
            if idx.entities:
                self._tenants[tenant] = idx

    def close(self) -> None:
        self._store.flush()
        del self._store
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None

    def add_listener(self, listener: ChangeListener) -> None:
        self._listeners.append(listener)

    # --- reads ---------------------------------------------------------------------------
    def entities(self, scope: ReadScope) -> list[Entity]:
        """Every entity the scope covers, oldest first (a snapshot)."""
        chunks = [list(idx.entities.values()) for tenant, idx in list(self._tenants.items())
                  if scope.covers(tenant)]
        if len(chunks) == 1:
            return chunks[0]
        out = [e for chunk in chunks for e in chunk]
        out.sort(key=lambda e: e.created)
        return out

    def get(self, scope: ReadScope, entity_id: str, entity_type: str | None) -> Entity:
        found = []
        for tenant, idx in list(self._tenants.items()):
            if scope.covers(tenant):
                by_type = idx.by_id.get(entity_id, {})
                if entity_type is None:
                    found.extend(by_type.values())
                elif entity_type in by_type:
                    found.append(by_type[entity_type])
        if not found:
            raise not_found()
        if len(found) > 1:
            raise too_many(entity_id)
        return found[0]

    def count(self) -> int:
        return sum(len(idx.entities) for idx in list(self._tenants.values()))

    def nquads(self) -> bytes:
        return self._store.dump(format=ox.RdfFormat.N_QUADS) or b""

    # --- writes --------------------------------------------------------------------------
    def write(self, tenant: Tenant, now: float, work: Callable[[Transaction], Any]) -> Any:
        """Run ``work`` on a transaction under the write lock, then make its changes durable,
        visible and known to the listeners. ``work`` raising writes nothing."""
        with self._write_lock:
            txn = Transaction(self, tenant, now)
            result = work(txn)
            if txn.pending:
                self._commit(txn)
            for change in txn.changes:
                for listener in self._listeners:
                    try:
                        listener.entity_changed(change)
                    except Exception:  # a listener's bug must not undo an acknowledged write
                        log.exception("change listener %r failed", listener)
            return result

    def _commit(self, txn: Transaction) -> None:
        """Write the difference between the indexed and the pending entities as one update.
        Only what changed is serialized: an attribute object a write kept is the same object,
        so its cached triples are reused."""
        idx = txn.idx
        delete: list[rdf.Triple] = []
        insert: list[rdf.Triple] = []
        plan = []
        for key, new in txn.pending.items():
            node = idx.nodes.get(key) or _choose_node(idx, key)
            old_head = idx.heads.get(key, frozenset())
            old_attrs = idx.attr_triples.get(key, {})
            new_head = rdf.head_triples(new, node) if new is not None else frozenset()
            new_attrs: dict[str, tuple[Any, frozenset[rdf.Triple]]] = {}
            if new is not None:
                for name, attr in new.attrs.items():
                    cached = old_attrs.get(name)
                    new_attrs[name] = cached if cached is not None and cached[0] is attr else (
                        attr, rdf.attribute_triples(new.id, new.type, name, attr))
            delete.extend(old_head - new_head)
            insert.extend(new_head - old_head)
            for name in old_attrs.keys() | new_attrs.keys():
                before, after = old_attrs.get(name), new_attrs.get(name)
                if before is not None and after is not None and before[0] is after[0]:
                    continue
                old_t = before[1] if before else frozenset()
                new_t = after[1] if after else frozenset()
                delete.extend(old_t - new_t)
                insert.extend(new_t - old_t)
            plan.append((key, new, node, new_head, new_attrs))
        text = rdf.update_text(rdf.graph_iri(txn.tenant), delete, insert)
        if text is not None:
            self._store.update(text)
        for key, new, node, head, attrs in plan:
            if new is None:
                _unindex(idx, key)
            else:
                _index(idx, new, node, head, attrs)
        if idx.entities:
            self._tenants[txn.tenant] = idx
        else:
            self._tenants.pop(txn.tenant, None)


def _choose_node(idx: _TenantIndex, key: Key) -> str:
    entity_id, entity_type = key
    preferred = rdf.preferred_node(entity_id, entity_type)
    taken = {idx.nodes.get((entity_id, t)) for t in idx.by_id.get(entity_id, {})}
    if preferred in taken:
        return rdf.minted_node(entity_id, entity_type)
    return preferred


def _index(idx: _TenantIndex, entity: Entity, node: str, head: frozenset[rdf.Triple] | None = None,
           attrs: dict[str, tuple[Any, frozenset[rdf.Triple]]] | None = None) -> None:
    key = (entity.id, entity.type)
    idx.entities[key] = entity
    idx.nodes[key] = node
    idx.heads[key] = head if head is not None else rdf.head_triples(entity, node)
    idx.attr_triples[key] = attrs if attrs is not None else {
        name: (attr, rdf.attribute_triples(entity.id, entity.type, name, attr))
        for name, attr in entity.attrs.items()}
    idx.by_id.setdefault(entity.id, {})[entity.type] = entity


def _unindex(idx: _TenantIndex, key: Key) -> None:
    idx.entities.pop(key, None)
    idx.nodes.pop(key, None)
    idx.heads.pop(key, None)
    idx.attr_triples.pop(key, None)
    by_type = idx.by_id.get(key[0])
    if by_type is not None:
        by_type.pop(key[1], None)
        if not by_type:
            idx.by_id.pop(key[0], None)


def _lock(path: Path) -> int:
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        os.close(fd)
        raise StoreLocked(f"the data folder {path.parent} is in use by another context broker "
                          f"process (lock {path} is held); stop it or choose another --data-dir") from None
    os.ftruncate(fd, 0)
    os.write(fd, f"{os.getpid()}\n".encode())
    return fd


__all__ = ["ContextStore", "ReadScope", "StoreLocked", "Transaction"]
