"""Bookkeeping that makes the worker lose nothing, kept apart from the I/O so it can be read and
unit-tested alone.

- :class:`InOrderAcks` (MQTT -> Kafka): an MQTT message is acknowledged only after Kafka confirmed
  its write, and PUBACKs leave in the order the PUBLISHes arrived (MQTT requires it), so a message
  confirmed early waits for the ones before it. Messages of a connection that dropped are never
  acknowledged: the broker sends them again on the next connection of the persistent session.
- :class:`PartitionLedger` (Kafka -> MQTT): the offsets of one partition published to MQTT and not
  yet committed. An offset is committed only when it and every offset before it were PUBACKed at
  least ``lag`` seconds earlier over the connection that is still up: Mosquitto keeps messages in
  memory, so one it acknowledged just before a SIGKILL may be gone; the worker then rewinds the
  partition to its committed offset and publishes again (duplicates, never gaps).
"""

from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field


@dataclass(eq=False)
class PendingAck:
    """One received QoS>0 MQTT message waiting for its Kafka confirmation."""

    mid: int
    qos: int
    generation: int
    confirmed: bool = False


class InOrderAcks:
    """Thread-safe: messages are added by the MQTT thread, confirmed by the Kafka thread."""

    def __init__(self, send_ack: Callable[[int, int], object]) -> None:
        self._send_ack = send_ack
        self._lock = threading.Lock()
        self._pending: deque[PendingAck] = deque()
        self._generation = 0

    def add(self, mid: int, qos: int) -> PendingAck:
        with self._lock:
            entry = PendingAck(mid, qos, self._generation)
            self._pending.append(entry)
            return entry

    def confirm(self, entry: PendingAck) -> int:
        """Mark ``entry`` written; send the PUBACKs now due, in order; return how many were sent."""
        sent = 0
        with self._lock:  # held while sending, so two threads never interleave PUBACKs
            if entry.generation != self._generation:
                return 0
            entry.confirmed = True
            while self._pending and self._pending[0].confirmed:
                head = self._pending.popleft()
                self._send_ack(head.mid, head.qos)
                sent += 1
        return sent

    def connection_lost(self) -> int:
        """Forget every unacknowledged message (the broker resends them); return how many."""
        with self._lock:
            dropped = len(self._pending)
            self._pending.clear()
            self._generation += 1
            return dropped

    def __len__(self) -> int:
        with self._lock:
            return len(self._pending)


@dataclass(eq=False)
class SentRecord:
    """One Kafka record of a partition, published to MQTT (or skipped: nothing to wait for)."""

    offset: int
    acked_at: float | None = None


@dataclass
class PartitionLedger:
    """Offsets of one partition between "consumed" and "committed" (single-threaded use)."""

    committed: int                      # the next offset to read after a rewind
    records: deque[SentRecord] = field(default_factory=deque)

    def sent(self, offset: int) -> SentRecord:
        record = SentRecord(offset)
        self.records.append(record)
        return record

    def skipped(self, offset: int) -> None:
        """A record not forwarded (our own, looped back): done at once."""
        self.records.append(SentRecord(offset, acked_at=float("-inf")))

    @staticmethod
    def acked(record: SentRecord, now: float) -> None:
        record.acked_at = now

    def commit_position(self, now: float, lag: float) -> int | None:
        """Drop the leading records PUBACKed at least ``lag`` s ago; the offset to commit
        (one past the last of them), or None if there is nothing new to commit."""
        position = None
        while self.records:
            head = self.records[0]
            if head.acked_at is None or head.acked_at > now - lag:
                break
            self.records.popleft()
            position = head.offset + 1
        return position

    def rewind(self) -> int:
        """Forget what was sent since the last commit; the offset to read again from."""
        self.records.clear()
        return self.committed
