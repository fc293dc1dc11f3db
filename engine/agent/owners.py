"""Who owns what on an agent: the plant recorded with each broker, topic and bridge.

Every request that creates or changes something may name its ``owner`` (the plant's owner name,
an IRI or a short name, see docs/operating.md); the agent keeps it in ``owner.json`` in the
folder of the broker (its own owner, its topics', its native bridges') or of the bridge worker, so
it survives an agent restart and re-adoption, and reports it in every answer (``owner``).

The rule the agent enforces, whatever the engine planned: a request that names an owner is refused
(409, :class:`OwnershipConflictError`) on a thing that *another* owner holds. A thing nobody owns
takes the owner of the first request that names one (an apply, or ``PUT .../owner``: import);
a request that names none leaves the recorded owner as it is (clients from before ownership).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from engine.agent.folder import write_atomic
from engine.agent.wire import WireError
from engine.errors import EngineError

OWNER_FILE = "owner.json"
OWNER_FIELD = "owner"
MAX_OWNER = 512


class OwnershipConflictError(EngineError):
    """The request names an owner, and another owner holds the thing (HTTP 409)."""


def check_owner(value: Any, where: str = OWNER_FIELD) -> str | None:
    """``value`` as an owner name (None if absent): 1 to 512 printable characters, no whitespace."""
    if value is None:
        return None
    if not isinstance(value, str):
        raise WireError(where, "expected a string (the owning plant's name or IRI)")
    if not 1 <= len(value) <= MAX_OWNER or not value.isprintable() \
            or any(c.isspace() for c in value):
        raise WireError(where, f"must be 1 to {MAX_OWNER} printable characters without whitespace "
                               "(the owning plant's name or IRI)")
    return value


def claim(current: str | None, given: str | None, what: str) -> str | None:
    """The owner ``what`` has after a request naming ``given``; raises if another one holds it."""
    if given is not None and current is not None and current != given:
        raise OwnershipConflictError(
            f"{what} is owned by plant {current!r}, not by {given!r}",
            hint="a plant changes only its own things: give yours another pk:id, or destroy it "
                 "from the plant that owns it")
    return given if given is not None else current


@dataclass
class Owners:
    """The owners recorded in one folder: the broker's (or worker bridge's) own, and for a broker
    its topics' (by name) and its native bridges' (by remote broker id). Guarded by the caller's
    per-folder operation lock."""

    path: Path
    owner: str | None = None
    topics: dict[str, str] = field(default_factory=dict)
    bridges: dict[str, str] = field(default_factory=dict)

    @classmethod
    def read(cls, folder: Path) -> Owners:
        """The record of ``folder`` (empty if none, or unreadable: then nobody owns anything)."""
        try:
            data = json.loads((folder / OWNER_FILE).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return cls(folder)
        if not isinstance(data, dict):
            return cls(folder)

        def names(value: Any) -> dict[str, str]:
            return {str(k): v for k, v in value.items() if isinstance(v, str)} \
                if isinstance(value, dict) else {}

        owner = data.get("owner")
        return cls(folder, owner if isinstance(owner, str) else None,
                   names(data.get("topics")), names(data.get("bridges")))

    def write(self) -> None:
        """Store the record atomically (the folder must exist)."""
        write_atomic(self.path / OWNER_FILE, json.dumps(
            {"owner": self.owner, "topics": self.topics, "bridges": self.bridges},
            indent=2, sort_keys=True) + "\n")

    def set_owner(self, owner: str | None) -> None:
        if owner != self.owner:
            self.owner = owner
            self.write()

    def set_topic(self, name: str, owner: str | None) -> None:
        """Record ``owner`` for topic ``name`` (None: forget it)."""
        if self.topics.get(name) != owner:
            self.topics = _with(self.topics, name, owner)  # a new dict: readers copy without a lock
            self.write()

    def set_bridge(self, remote_id: str, owner: str | None) -> None:
        """Record ``owner`` for the native bridge to ``remote_id`` (None: forget it)."""
        if self.bridges.get(remote_id) != owner:
            self.bridges = _with(self.bridges, remote_id, owner)
            self.write()


def _with(table: dict[str, str], key: str, owner: str | None) -> dict[str, str]:
    out = {k: v for k, v in table.items() if k != key}
    if owner is not None:
        out[key] = owner
    return out
