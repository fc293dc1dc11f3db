"""The durable context: an on-disk Oxigraph store (RDF, one named graph per tenant) with an
in-memory index of the entities for reads.

- Every write runs under one write lock: it looks the entities up in the index, computes the new
  ones (pure functions of :mod:`.entities`; a refusal raises before anything is written), appends
  the difference of their triples to the write-ahead log (:mod:`.wal`, ONE ``os.write``: in the
  OS page cache when it returns, so an acknowledged write survives kill -9), then swaps the new
  immutable :class:`Entity` objects into the index and tells every :class:`ChangeListener`, in
  write order, before the caller answers.
- A background thread (the applier) takes the logged changes not yet in Oxigraph, nets them
  (each triple's last state wins) and writes them as ONE SPARQL Update per batch (it waits
  ``APPLY_DELAY`` after the first to gather more); when the log
  passes ``ROTATE_BYTES`` it rotates it and deletes the old file once all of it is applied.
  Replaying a suffix of the log on a store that already holds some of it gives the same store
  (each record sets its triples absent or present), so no applied-up-to mark is needed.
- At start the log (``context.wal.old`` then ``context.wal``) is replayed into Oxigraph, a torn
  last record (killed mid-write, never acknowledged) dropped; then the logs are emptied.
  :meth:`ContextStore.nquads` applies what is pending first, so it shows every answered write.
- Reads take no lock: the index holds immutable entities and a write replaces them whole, so a
  reader sees an entity before or after a write, never half of one.
- Then the index is rebuilt from the store (:func:`.rdf.entities_from_quads`).
- ``ContextStore(None)`` (in memory, for tests) has no log: it updates Oxigraph directly.
- ``data_dir/context.lock`` (``flock``) keeps a second process off the same folder.
"""

from __future__ import annotations

import fcntl
import json
import logging
import os
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pyoxigraph as ox

from engine.context_broker import rdf
from engine.context_broker.wal import WriteAheadLog, read_records
from engine.context_broker.contract import ChangeListener, EntityChange, NgsiError, Tenant, not_found
from engine.context_broker.entities import Entity

log = logging.getLogger(__name__)
Key = tuple[str, str]
LOCK_FILE = "context.lock"
STORE_DIR = "oxigraph"
WAL_FILE = "context.wal"
ROTATE_BYTES = 8 * 1024 * 1024
APPLY_DELAY = 0.02
#: One logged change: the tenant's graph IRI, the triples deleted, the triples inserted.
Change = tuple[str, list[rdf.Triple], list[rdf.Triple]]


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
    """``ContextStore(data_dir)`` durable; ``ContextStore(None)`` in memory (tests).
    ``fsync``: also ``fdatasync`` the log before each write is answered (survives power loss)."""

    def __init__(self, data_dir: Path | str | None = None, *, fsync: bool = False) -> None:
        self._lock_fd: int | None = None
        self._wal: WriteAheadLog | None = None
        self._write_lock = threading.Lock()
        self._apply_lock = threading.Lock()
        self._cv = threading.Condition(threading.Lock())
        self._pending: list[Change] = []
        self._stopping = False
        self._failed = False
        self._applier: threading.Thread | None = None
        self._listeners: list[ChangeListener] = []
        self._tenants: dict[Tenant, _TenantIndex] = {}
        if data_dir is None:
            self._store = ox.Store()
        else:
            root = Path(data_dir)
            root.mkdir(parents=True, exist_ok=True)
            self._lock_fd = _lock(root / LOCK_FILE)
            self._store = ox.Store(str(root / STORE_DIR))
            self._wal = WriteAheadLog(self._replay(root / WAL_FILE), fsync=fsync)
            self._applier = threading.Thread(target=self._apply_loop, name="context-store-applier",
                                             daemon=True)
        self._load()
        if self._applier is not None:
            self._applier.start()

    def _replay(self, path: Path) -> Path:
        """Apply what the logs hold to Oxigraph (the old file first), then delete them."""
        old = path.with_name(path.name + ".old")
        changes: list[Change] = []
        last = None
        for log_path in (old, path):
            records, torn = read_records(log_path, last)
            if torn:
                log.warning("%s: dropped a torn or broken record after %d whole ones (a write "
                            "cut by a crash, never acknowledged)", log_path, len(records))
            if records:
                last = records[-1].seq
            changes.extend(_decode(r.payload) for r in records)
        text = net_update(changes)
        if text is not None:
            self._store.update(text)
            self._store.flush()
            log.info("replayed %d logged changes into the store", len(changes))
        old.unlink(missing_ok=True)
        return path

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
        if self._applier is not None:
            with self._cv:
                self._stopping = True
                self._cv.notify()
            self._applier.join()
            self._applier = None
        self.sync()
        self._store.flush()
        if self._wal is not None:
            self._wal.close(remove=not self._failed)
            self._wal = None
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
        """The store as N-Quads, with every answered write (what is pending is applied first)."""
        self.sync()
        return self._store.dump(format=ox.RdfFormat.N_QUADS) or b""

    # --- the log's applier ---------------------------------------------------------------
    def sync(self) -> None:
        """Apply every logged change not yet in Oxigraph; rotate the log when it is large."""
        if self._wal is None:
            return
        with self._apply_lock:
            with self._cv:
                batch, self._pending = self._pending, []
            self._apply(batch)
            wal = self._wal
            if wal.size > ROTATE_BYTES and not self._failed:
                with self._write_lock:
                    wal.rotate()
                    with self._cv:
                        batch, self._pending = self._pending, []
                self._apply(batch)
                if not self._failed:
                    wal.discard_old()

    def _apply(self, batch: list[Change]) -> None:
        text = net_update(batch)
        if text is None:
            return
        try:
            self._store.update(text)
        except Exception:  # a bug: keep the log (replayed at the next start) and say so
            self._failed = True
            log.exception("applying %d logged changes to Oxigraph failed; the log is kept and "
                          "replayed at the next start", len(batch))

    def _apply_loop(self) -> None:
        while True:
            with self._cv:
                while not self._pending and not self._stopping:
                    self._cv.wait()
                if self._stopping:
                    return
                self._cv.wait(APPLY_DELAY)  # gather a batch: its writes are answered already
                if self._stopping:
                    return
            self.sync()

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
        if delete or insert:
            self._log((rdf.graph_iri(txn.tenant), delete, insert))
        for key, new, node, head, attrs in plan:
            if new is None:
                _unindex(idx, key)
            else:
                _index(idx, new, node, head, attrs)
        if idx.entities:
            self._tenants[txn.tenant] = idx
        else:
            self._tenants.pop(txn.tenant, None)


    def _log(self, change: Change) -> None:
        """Make one write's change durable (the log) and queue it for Oxigraph; in memory: apply it."""
        if self._wal is None:
            text = net_update([change])
            if text is not None:
                self._store.update(text)
            return
        self._wal.append(json.dumps(change, ensure_ascii=False, separators=(",", ":")).encode())
        with self._cv:
            self._pending.append(change)
            if len(self._pending) == 1:
                self._cv.notify()


def net_update(changes: list[Change]) -> str | None:
    """One SPARQL Update with the net effect of ``changes`` in order: per graph, each triple ends
    as the last change that names it left it. On a store holding any prefix of ``changes`` it
    gives the store all of them give."""
    graphs: dict[str, dict[rdf.Triple, bool]] = {}
    for graph, delete, insert in changes:
        state = graphs.setdefault(graph, {})
        for triple in delete:
            state[triple] = False
        for triple in insert:
            state[triple] = True
    texts = []
    for graph, state in graphs.items():
        text = rdf.update_text(graph, [t for t, on in state.items() if not on],
                               [t for t, on in state.items() if on])
        if text is not None:
            texts.append(text)
    return " ;\n".join(texts) or None


def _decode(payload: bytes) -> Change:
    graph, delete, insert = json.loads(payload)
    return graph, [tuple(t) for t in delete], [tuple(t) for t in insert]


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
