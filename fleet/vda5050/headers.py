"""VDA 5050 message headers: ``headerId`` counted per topic, ISO 8601 UTC timestamps with ms.

Section 6.4: every message carries ``headerId`` (incremented by 1 per topic and sender),
``timestamp`` (ISO 8601, UTC, e.g. ``2026-11-24T16:55:20.123Z``), ``version`` (``2.1.0``),
``manufacturer`` and ``serialNumber``. The counter is an object the sender owns (one per vehicle),
the clock is passed in so tests fix the time.
"""

from __future__ import annotations

from collections.abc import Callable
from datetime import datetime, timezone

from fleet.vda5050 import VERSION
from fleet.vda5050.topics import Subtopic, check_level, check_serial

Clock = Callable[[], datetime]


def utc_now() -> datetime:
    return datetime.now(timezone.utc)


def timestamp(moment: datetime) -> str:
    """ISO 8601 in UTC with milliseconds and a ``Z``; a naive datetime is refused (whose zone?)."""
    if moment.tzinfo is None:
        raise ValueError("timestamp needs an aware datetime (UTC); got a naive one")
    return moment.astimezone(timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")


class HeaderCounter:
    """The header source of one sender (a vehicle or a master talking to one vehicle).

    Not thread-safe on purpose: each vehicle's messages are built by one thread.
    """

    def __init__(self, manufacturer: str, serial: str, clock: Clock = utc_now) -> None:
        self.manufacturer = check_level("manufacturer", manufacturer)
        self.serial = check_serial(serial)
        self._clock = clock
        self._next: dict[Subtopic, int] = {}

    def next(self, subtopic: Subtopic | str) -> dict[str, object]:
        """The header fields of the next message on ``subtopic`` (camelCase, ready for JSON)."""
        kind = Subtopic(subtopic)
        header_id = self._next.get(kind, 0)
        self._next[kind] = header_id + 1
        return {
            "headerId": header_id,
            "timestamp": timestamp(self._clock()),
            "version": VERSION,
            "manufacturer": self.manufacturer,
            "serialNumber": self.serial,
        }

    def peek(self, subtopic: Subtopic | str) -> int:
        return self._next.get(Subtopic(subtopic), 0)
