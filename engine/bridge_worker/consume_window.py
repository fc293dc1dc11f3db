"""When the Kafka -> MQTT half takes more records from Kafka, waits for PUBACKs, or pauses its
partitions: a pure decision, kept apart from the I/O so it can be unit-tested alone.

Why not simply pause the partitions whenever too many records wait for their PUBACK: librdkafka
drops what it already fetched for a paused partition, and after a resume its fetcher only looks at
the partition again on its next once-a-second tick (librdkafka 2.16, ``debug=fetch`` in the bridge
benchmark: "is fetchable" logged 0.86-0.92 s after the resumes). Pausing at every full window held
the worker at ~7,000 msg/s, idle most of the time. So a full window first only stops the consuming:
the records stay fetched, and consuming goes on as PUBACKs come back. Only a window full for
longer than ``hold_limit`` (the broker takes nothing: its PUBACKs are not coming) pauses the
partitions, because the consumer must then be polled again (rebalances, ``max.poll.interval.ms``).

Hysteresis: a full window reopens only once ``low`` records or fewer wait, so consuming goes
on in batches rather than one record per PUBACK.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class Flow(enum.Enum):
    CONSUME = "consume"          # poll Kafka for records (partitions resumed)
    AWAIT_ACKS = "await-acks"    # the window is full: wait for PUBACKs, do not poll Kafka
    PAUSE = "pause"              # partitions paused; poll Kafka only for its callbacks


@dataclass
class ConsumeWindow:
    """``high``: records published and not PUBACKed at which consuming stops; ``low``: at or
    below which it goes on; ``hold_limit``: seconds a full window may last before the
    partitions are paused."""

    high: int
    low: int
    hold_limit: float
    full_since: float | None = None

    def __post_init__(self) -> None:
        if not 0 <= self.low < self.high:
            raise ValueError(f"consume window: low ({self.low}) must be in 0..high ({self.high}) - 1")

    def decide(self, connected: bool, unacked: int, now: float) -> Flow:
        if not connected:
            self.full_since = None
            return Flow.PAUSE
        if self.full_since is None:
            if unacked < self.high:
                return Flow.CONSUME
            self.full_since = now
        elif unacked <= self.low:
            self.full_since = None
            return Flow.CONSUME
        return Flow.PAUSE if now - self.full_since >= self.hold_limit else Flow.AWAIT_ACKS
