"""What the planner's event sources (MQTT, the context broker) share: one way into ``Planner.fire``
and one tally of what came in, what fired and what was refused (issue 12: operator buttons and
sensors fire LoTLan Events without calling the planner's API themselves).

A source turns its message into ``(name, value)`` (pure, per source: :mod:`events_mqtt`,
:mod:`events_ngsi`) and hands it to :meth:`Tally.deliver`, which calls the same ``fire`` as
``POST /v1/events`` — so the event is checked against the Event's type, numbered and journaled
the same way. A refusal (unknown event, wrong type, a message that is no event) is logged with
where it came from and the reason, counted, and kept among the last few for the status; it never
stops the source or the planner.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from fleet.discovery.records import now_iso
from fleet.planner.errors import PlannerError

log = logging.getLogger("fleet.planner.events")
#: ``fire(name, value)`` -> the journaled event; raises :class:`PlannerError` (``RequestError``) when refused.
Fire = Callable[[Any, Any], dict[str, Any]]
KEEP = 10  # the last refusals shown in the status


class EventMessageError(PlannerError):
    """A message that is no event: ``field`` names what is wrong (``payload``, ``topic``, ``data[1].value``)."""

    def __init__(self, field: str, reason: str) -> None:
        super().__init__(f"{field}: {reason}")
        self.field, self.reason = field, reason


@dataclass(frozen=True)
class Refusal:
    source: str  # "mqtt" or "ngsi"
    where: str  # the topic, or the entity id in a notification
    reason: str
    at: str

    def to_json(self) -> dict[str, str]:
        return {"source": self.source, "where": self.where, "reason": self.reason, "at": self.at}


class Tally:
    """Counts of one source; thread-safe (paho's thread and the API's threads deliver)."""

    def __init__(self, source: str, fire: Fire) -> None:
        self.source, self.fire = source, fire
        self._lock = threading.Lock()
        self.received = self.fired = self.refused = 0
        self.last: deque[Refusal] = deque(maxlen=KEEP)

    def deliver(self, where: str, name: str, value: Any) -> dict[str, Any] | Refusal:
        """Fire ``name`` = ``value``: the journaled event, or the :class:`Refusal` when the planner refused it."""
        with self._lock:
            self.received += 1
        try:
            record = self.fire(name, value)
        except PlannerError as exc:
            return self.refuse(where, str(exc), counted=True)
        with self._lock:
            self.fired += 1
        log.info("%s %s: event %s = %r fired (number %s)", self.source, where, record.get("event"), value,
                 record.get("number"))
        return record

    def refuse(self, where: str, reason: str, *, counted: bool = False) -> Refusal:
        """Count and log a message that fired nothing (``counted``: it was counted as received already)."""
        refusal = Refusal(self.source, where, reason[:300], now_iso())
        with self._lock:
            if not counted:
                self.received += 1
            self.refused += 1
            self.last.append(refusal)
        log.warning("%s %s: refused, %s", self.source, where, refusal.reason)
        return refusal

    def status(self) -> dict[str, Any]:
        with self._lock:
            return {"received": self.received, "fired": self.fired, "refused": self.refused,
                    "lastRefusals": [r.to_json() for r in self.last]}
