"""The data directory of plug and play: one record and one Turtle file per discovered vehicle.

::

    <data-dir>/discovered/<manufacturer>--<serial>.ttl    the vehicle in the plant's graph
    <data-dir>/vehicles/<manufacturer>--<serial>.json      its record (the truth the .ttl is rendered from)
    <data-dir>/refused/<manufacturer>--<serial>.{ttl,json} a refused vehicle, with .reason.txt beside it
    <data-dir>/status.json                                 the manager's status (fleet.manager.status)

A vehicle a person admitted (``plantkg fleet admit``, :mod:`fleet.discovery.admission`) has a
record before it is heard: its identity, its ``secret_ref`` and ``awaiting_description``; its first
description fills it in and keeps the ``secret_ref``.

The record keeps what a person decided (``pinned``, ``name``) and the last connection state, plus
the description and the plant binding it was rendered with, so the Turtle can be rendered again
(``plantkg fleet rename``) without the plant. Every write is atomic (``files.atomic_write``);
read-modify-write happens under ``files.locked(data_dir)``. Rendering is injected (``Render``)
so this module does not decide what the Turtle says.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import asdict, dataclass, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from fleet.discovery import files
from fleet.discovery.errors import DataDirError, UnknownVehicleError


@dataclass(frozen=True)
class VehicleRecord:
    interface: str            # "vda5050" | "paper-channels"
    manufacturer: str         # the description's manufacturer
    serial: str
    topic_manufacturer: str   # the manufacturer topic level ("" for paper vehicles)
    description: dict[str, Any]
    binding: dict[str, Any]
    connection_state: str = "ONLINE"
    pinned: bool = False
    name: str | None = None   # a person's rename (pk:name), None: the vehicle's own
    discovered_at: str = ""
    #: where its password is (pk:secretRef): a vehicle a person admitted to a closed broker
    secret_ref: str | None = None
    #: admitted, its own description not heard yet: ``description`` is its identity only
    awaiting_description: bool = False

    @property
    def stem(self) -> str:
        return files.stem(self.manufacturer, self.serial)

    @property
    def label(self) -> str:
        return f"{self.manufacturer}/{self.serial}"

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> VehicleRecord:
        return cls(**data)


#: record -> the vehicle's whole Turtle document
Render = Callable[[VehicleRecord], str]


def now_iso() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")


class DataDir:
    """The folders above, and the operations on them (callers hold ``lock()`` when they mix
    reads and writes that must not interleave with another process)."""

    def __init__(self, root: Path | str, render: Render) -> None:
        self.root = Path(root)
        self.render = render
        self.discovered = self.root / "discovered"
        self.vehicles = self.root / "vehicles"
        self.refused = self.root / "refused"

    def lock(self) -> Any:
        return files.locked(self.root)

    # ----------------------------------------------------------------- reading
    def records(self) -> list[VehicleRecord]:
        out = []
        for path in sorted(self.vehicles.glob("*.json")) if self.vehicles.is_dir() else ():
            try:
                out.append(VehicleRecord.from_json(json.loads(path.read_text(encoding="utf-8"))))
            except (OSError, ValueError, TypeError) as exc:
                raise DataDirError(f"{path}: not a vehicle record ({exc})",
                                   hint="remove the file, or restore it from the .ttl's vehicle") from None
        return out

    def turtle_files(self) -> list[Path]:
        """The discovered vehicles' Turtle files, sorted (what the plant's files are joined with)."""
        return sorted(self.discovered.glob("*.ttl")) if self.discovered.is_dir() else []

    def find(self, name: str) -> VehicleRecord:
        """A record by ``SERIAL`` or ``MANUFACTURER/SERIAL``."""
        records = self.records()
        hits = [r for r in records if name in (r.serial, r.label, r.stem)]
        if len(hits) != 1:
            raise UnknownVehicleError(name, [r.label for r in records]) if not hits else DataDirError(
                f"{name!r} names {len(hits)} vehicles ({', '.join(r.label for r in hits)})",
                hint="name it as MANUFACTURER/SERIAL")
        return hits[0]

    def turtle_path(self, record: VehicleRecord) -> Path:
        return self.discovered / f"{record.stem}.ttl"

    # ----------------------------------------------------------------- writing
    def save(self, record: VehicleRecord) -> Path:
        """Render and write the vehicle's Turtle, then its record; returns the Turtle's path."""
        path = self.turtle_path(record)
        files.atomic_write(path, self.render(record))
        files.atomic_write(self.vehicles / f"{record.stem}.json",
                           json.dumps(record.to_json(), indent=2, sort_keys=True) + "\n")
        return path

    def update(self, record: VehicleRecord, **changes: Any) -> VehicleRecord:
        new = replace(record, **changes)
        if new != record:
            self.save(new)
        return new

    def remove(self, record: VehicleRecord) -> None:
        """The record first: a crash in between leaves a Turtle file nobody claims (written over
        when the vehicle is discovered again), never a record whose file is gone."""
        for path in (self.vehicles / f"{record.stem}.json", self.turtle_path(record)):
            path.unlink(missing_ok=True)
        files.fsync_dir(self.discovered) if self.discovered.is_dir() else None

    def refuse(self, stem: str, reason: str, *, turtle: Path | None = None,
               payload: dict[str, Any] | None = None) -> Path:
        """Keep a refused vehicle under refused/ with its reason; the discovered file (if any) moves
        there, its record is dropped. Returns the reason file."""
        self.refused.mkdir(parents=True, exist_ok=True)
        if turtle is not None and turtle.exists():
            files.move(turtle, self.refused / f"{stem}.ttl")
        (self.vehicles / f"{stem}.json").unlink(missing_ok=True)
        if payload is not None:
            files.atomic_write(self.refused / f"{stem}.json", json.dumps(payload, indent=2)[:1_000_000])
        why = self.refused / f"{stem}.reason.txt"
        files.atomic_write(why, f"{now_iso()} {reason}\n")
        return why

    def refused_list(self) -> list[dict[str, str]]:
        if not self.refused.is_dir():
            return []
        return [{"vehicle": p.name[: -len(".reason.txt")], "reason": p.read_text(encoding="utf-8").strip()}
                for p in sorted(self.refused.glob("*.reason.txt"))]
