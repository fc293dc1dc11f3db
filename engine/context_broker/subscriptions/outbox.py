"""The notifications not yet delivered, on disk: a write answered 2xx keeps its notifications
through a kill -9 of the context broker (and through a clean stop with a receiver down).

One append-only file, ``outbox.log`` in the subscriptions folder, framed like the context
store's write-ahead log (:mod:`engine.context_broker.wal`: one ``os.write`` per record, a torn
tail dropped at start). Two kinds of record:

- ``Q`` + id + the notification (JSON): appended by :meth:`Outbox.add` on the writing request's
  thread, before the write is answered;
- ``A`` + ids: appended by :meth:`Outbox.settle` once those notifications are done with —
  delivered, refused for good by their receiver, or thrown away with their subscription or by
  the lane's bound (each of those is counted on the subscription, as before).

At start (:meth:`Outbox.recover`) the queued records without an ``A`` are the notifications to
send again, in their original order; the file is rewritten with only them (a new file renamed
over the old, so a kill mid-way leaves one or the other). The same compaction runs when the file
passes ``compact_bytes``. Delivery is at least once: a notification sent just before a kill, its
``A`` not yet written, is sent again after the restart, as Orion's own retries may.
"""

from __future__ import annotations

import json
import os
import struct
import threading
from dataclasses import replace
from pathlib import Path

from engine.context_broker.subscriptions.render import Outgoing
from engine.context_broker.wal import WriteAheadLog, read_records

QUEUED = b"Q"
SETTLED = b"A"
ID = struct.Struct("<Q")
COMPACT_BYTES = 16 * 1024 * 1024
FILE_NAME = "outbox.log"


def _encode(msg: Outgoing) -> bytes:
    return json.dumps({"s": msg.subscription_id, "b": msg.body.decode("utf-8"), "f": msg.attrs_format,
                       "sv": msg.service, "sp": msg.service_path, "e": msg.entity_id,
                       "c": msg.correlator}, separators=(",", ":")).encode()


def _decode(outbox_id: int, data: bytes) -> Outgoing:
    doc = json.loads(data)
    return Outgoing(subscription_id=doc["s"], body=doc["b"].encode("utf-8"), attrs_format=doc["f"],
                    service=doc["sv"], service_path=doc["sp"], entity_id=doc["e"],
                    correlator=doc["c"], outbox_id=outbox_id)


class Outbox:
    """``add`` before a write is answered, ``settle`` when done; thread-safe."""

    def __init__(self, folder: Path, *, fsync: bool = False, compact_bytes: int = COMPACT_BYTES) -> None:
        self.path = Path(folder) / FILE_NAME
        self._fsync = fsync
        self._compact_bytes = compact_bytes
        self._lock = threading.Lock()
        self._pending: dict[int, Outgoing] = {}
        self._next_id = 1
        self._log: WriteAheadLog | None = None

    def recover(self) -> list[Outgoing]:
        """Read the file left by the last run; the notifications it did not settle, in order.
        Opens the file for this run (compacted to just those)."""
        records, _torn = read_records(self.path)
        pending: dict[int, Outgoing] = {}
        for record in records:
            kind, body = record.payload[:1], record.payload[1:]
            if kind == QUEUED:
                outbox_id = ID.unpack_from(body)[0]
                pending[outbox_id] = _decode(outbox_id, body[ID.size:])
                self._next_id = max(self._next_id, outbox_id + 1)
            elif kind == SETTLED:
                for (outbox_id,) in ID.iter_unpack(body):
                    pending.pop(outbox_id, None)
        with self._lock:
            self._pending = pending
            self._rewrite()
        return list(pending.values())

    def add(self, msg: Outgoing) -> Outgoing:
        """Log ``msg``; the same notification carrying its outbox id (settle that one)."""
        with self._lock:
            log = self._open()
            outbox_id = self._next_id
            self._next_id += 1
            tagged = replace(msg, outbox_id=outbox_id)
            log.append(QUEUED + ID.pack(outbox_id) + _encode(msg))
            self._pending[outbox_id] = tagged
            return tagged

    def settle(self, msgs: list[Outgoing]) -> None:
        ids = [m.outbox_id for m in msgs if m.outbox_id]
        if not ids:
            return
        with self._lock:
            log = self._open()
            for outbox_id in ids:
                self._pending.pop(outbox_id, None)
            log.append(SETTLED + b"".join(ID.pack(i) for i in ids))
            if log.size > self._compact_bytes:
                self._rewrite()

    def pending(self) -> int:
        with self._lock:
            return len(self._pending)

    def close(self) -> None:
        with self._lock:
            if self._log is not None:
                self._log.close()
                self._log = None

    def _open(self) -> WriteAheadLog:
        if self._log is None:
            self._rewrite()
        assert self._log is not None
        return self._log

    def _rewrite(self) -> None:
        """A new file with only the pending notifications, renamed over the old (lock held)."""
        if self._log is not None:
            self._log.close()
            self._log = None
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fresh = self.path.with_name(FILE_NAME + ".new")
        log = WriteAheadLog(fresh, fsync=self._fsync)
        for outbox_id, msg in self._pending.items():
            log.append(QUEUED + ID.pack(outbox_id) + _encode(msg))
        log.close()
        os.replace(fresh, self.path)
        self._log = WriteAheadLog(self.path, fsync=self._fsync, truncate=False,
                                  next_seq=len(self._pending) + 1)
        self._log.size = self.path.stat().st_size


__all__ = ["Outbox"]
