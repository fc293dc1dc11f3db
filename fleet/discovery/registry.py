"""What plug and play does about each event: a pure state machine returning effects as data.

The fleet manager feeds it every accepted event (``inbox``) with the time; it answers with
effects the manager carries out (publish, write, refuse, reconcile). No I/O here, so every rule
is a unit test:

- an unknown vehicle that says ONLINE is asked for its factsheet (:class:`AskFactsheet`), at
  most once per ``ask_every`` seconds however many ONLINE messages it sends (a flood makes no
  duplicates); so is a vehicle a person admitted whose description was not heard yet
  (``Known.awaiting``), and its first description joins it as new;
- a description (factsheet or paper description) of an unknown vehicle joins it (:class:`Join`);
  the same description again changes nothing; a different one updates it (:class:`Join` again),
  unless a person pinned the vehicle (:class:`Note`, nothing changes);
- a description the model refuses is refused (:class:`Refuse`) with the reason, once per
  description;
- OFFLINE / CONNECTIONBROKEN (the paper: ``"state": "OFFLINE"``) of a known vehicle marks it
  unavailable (:class:`SetConnection`), ONLINE marks it available again; it is never deleted;
- every ``state`` is kept (:class:`Track`) for orders and the status file.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

from fleet.discovery.inbox import ConnectionSeen, DescriptionSeen, Event, Interface, StateSeen, VehicleKey, VehicleState


class DescriptionRefused(Exception):
    """The model cannot make a description of this payload; ``reason`` names field and value."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


#: (key, payload) -> the AgvDescription as JSON, or DescriptionRefused
Describe = Callable[[VehicleKey, dict[str, Any]], dict[str, Any]]


@dataclass(frozen=True)
class Known:
    """A discovered vehicle as the registry remembers it."""

    description: dict[str, Any]
    connection_state: str
    pinned: bool = False
    awaiting: bool = False  # admitted by a person; its own description not heard yet


# ----------------------------------------------------------------------------- effects

@dataclass(frozen=True)
class AskFactsheet:
    key: VehicleKey


@dataclass(frozen=True)
class Join:
    """Write the vehicle's file (new, or its description changed) and reconcile."""

    key: VehicleKey
    description: dict[str, Any]
    connection_state: str
    new: bool


@dataclass(frozen=True)
class SetConnection:
    key: VehicleKey
    state: str


@dataclass(frozen=True)
class Refuse:
    key: VehicleKey
    reason: str
    payload: dict[str, Any]


@dataclass(frozen=True)
class Track:
    key: VehicleKey
    state: VehicleState


@dataclass(frozen=True)
class Note:
    """Something worth a log line that changes nothing."""

    key: VehicleKey
    message: str


Effect = AskFactsheet | Join | SetConnection | Refuse | Track | Note


def _fingerprint(payload: dict[str, Any]) -> str:
    body = {k: v for k, v in payload.items() if k not in ("headerId", "timestamp", "header")}
    return json.dumps(body, sort_keys=True, default=str)


class Registry:
    """Known vehicles, last connection states, factsheet requests in flight."""

    def __init__(self, describe: Describe, *, ask_every: float = 5.0, max_unknown: int = 10_000) -> None:
        self.describe = describe
        self.ask_every = ask_every
        self.max_unknown = max_unknown  # unknown vehicles remembered at most (a flood of made-up serials)
        self.known: dict[VehicleKey, Known] = {}
        self.connection: dict[VehicleKey, str] = {}
        self.asked: dict[VehicleKey, float] = {}
        self.refused: dict[VehicleKey, str] = {}  # key -> fingerprint of the refused payload
        self.described: dict[VehicleKey, str] = {}  # key -> fingerprint of the joined payload

    def load(self, known: dict[VehicleKey, Known]) -> None:
        """Replace what is known (at start, and after a person changed the data directory)."""
        self.known = dict(known)

    def forget(self, key: VehicleKey) -> None:
        self.known.pop(key, None)
        self.asked.pop(key, None)

    def reject(self, key: VehicleKey) -> None:
        """A joined vehicle made the plant invalid: forget it, and refuse the same description
        again without asking the model (a new description, or coming back online, tries again)."""
        self.known.pop(key, None)
        if key in self.described:
            self.refused[key] = self.described[key]

    def _forget_oldest_unknown(self) -> None:
        for old in list(self.connection):
            if old not in self.known:
                del self.connection[old]
                self.asked.pop(old, None)
                self.refused.pop(old, None)
                self.described.pop(old, None)
                return

    def handle(self, event: Event, now: float) -> list[Effect]:
        if isinstance(event, ConnectionSeen):
            return self._connection(event, now)
        if isinstance(event, DescriptionSeen):
            return self._description(event)
        if isinstance(event, StateSeen):
            return [Track(event.key, event.state)]
        raise TypeError(f"not an event: {event!r}")

    def _connection(self, event: ConnectionSeen, now: float) -> list[Effect]:
        key, state = event.key, event.state
        before = self.connection.pop(key, None)
        self.connection[key] = state  # (re)inserted last: the oldest unknown ones are forgotten first
        if len(self.connection) > len(self.known) + self.max_unknown:
            self._forget_oldest_unknown()
        known = self.known.get(key)
        if known is not None:
            changed = known.connection_state != state
            if changed:
                self.known[key] = replace(known, connection_state=state)
            out: list[Effect] = [SetConnection(key, state)] if changed else []
            if known.awaiting and state == "ONLINE" and key.interface is Interface.VDA5050:
                out += self._ask(key, now)
            return out
        if state != "ONLINE" or key.interface is not Interface.VDA5050:
            return []  # a paper vehicle describes itself on description_channel
        if before != "ONLINE":
            self.refused.pop(key, None)  # it came (back) online: give it another chance
        return self._ask(key, now)

    def _ask(self, key: VehicleKey, now: float) -> list[Effect]:
        """Ask for the factsheet, at most once per ``ask_every`` seconds."""
        last = self.asked.get(key)
        if last is not None and now - last < self.ask_every:
            return []
        self.asked[key] = now
        return [AskFactsheet(key)]

    def _description(self, event: DescriptionSeen) -> list[Effect]:
        key = event.key
        known = self.known.get(key)
        if event.payload is None:  # the paper's "removed": unavailable, never deleted
            if known is None or known.connection_state == "OFFLINE":
                return []
            self.known[key] = replace(known, connection_state="OFFLINE")
            return [SetConnection(key, "OFFLINE")]
        fingerprint = _fingerprint(event.payload)
        if self.refused.get(key) == fingerprint:
            return []
        try:
            description = self.describe(key, event.payload)
        except DescriptionRefused as exc:
            self.refused[key] = fingerprint
            return [Refuse(key, exc.reason, event.payload)]
        self.refused.pop(key, None)
        self.asked.pop(key, None)
        self.described[key] = fingerprint
        if known is not None and known.awaiting:  # admitted: its first own description
            self.known[key] = replace(known, description=description, awaiting=False)
            return [Join(key, description, known.connection_state, new=True)]
        if known is not None:
            if known.description == description:
                return []
            if known.pinned:
                return [Note(key, "pinned: its new description is ignored (unpin to accept it)")]
            self.known[key] = replace(known, description=description)
            return [Join(key, description, known.connection_state, new=False)]
        default = "ONLINE" if key.interface is Interface.PAPER else "OFFLINE"
        state = self.connection.get(key, default)
        self.known[key] = Known(description, state)
        return [Join(key, description, state, new=True)]
