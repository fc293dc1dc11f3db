"""The one place plug and play calls the AGV model (``fleet.model``, owned by another part).

Everything it needs of the model goes through these functions: a description from a factsheet
or a paper description, the plant's fleet binding, the Turtle of a vehicle, and the JSON form of
a description and a binding (kept in the vehicle's record so ``plantkg fleet rename`` can render
the file again without the plant). The imports are made when a function is called, so this
package imports (and its pure parts are testable) on their own.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterable
from pathlib import Path
from typing import Any


def describe_factsheet(manufacturer: str, serial: str, payload: dict[str, Any]) -> Any:
    """An AgvDescription from a VDA 5050 factsheet; DescriptionError names the bad field."""
    from fleet.model.description import from_factsheet

    return from_factsheet(manufacturer, serial, payload)


def describe_paper(payload: dict[str, Any]) -> Any:
    """An AgvDescription from the paper's description_channel payload."""
    from fleet.model.description import from_paper_description

    return from_paper_description(payload)


def description_errors() -> tuple[type[Exception], ...]:
    """The exception types a description can be refused with."""
    from fleet.model.errors import DescriptionError

    return (DescriptionError,)


def plant_binding(files: Iterable[Path | str]) -> Any:
    """The plant's FleetBinding (MQTT broker of the fleet manager, context broker, base IRI)."""
    from fleet.model.binding import fleet_binding

    return fleet_binding([Path(f) for f in files])


def render(description: Any, binding: Any, *, connection_state: str, pinned: bool,
           secret_ref: str | None = None, discovered: bool = True) -> str:
    from fleet.model.graph import agv_turtle

    return agv_turtle(description, binding, connection_state=connection_state, pinned=pinned,
                      secret_ref=secret_ref, discovered=discovered)


def resource_id(serial: str) -> str:
    """The vehicle's ``pk:id`` (``agv-<serial>``, made safe): its user name on a closed broker."""
    from fleet.model.graph import agv_id

    return f"agv-{agv_id(serial)}"


def admitted_description(interface: str, manufacturer: str, serial: str) -> dict[str, Any]:
    """The description of a vehicle a person admitted before it was heard: its identity only (no
    skills, no properties), named ``<manufacturer> <serial>``; its factsheet replaces it."""
    from fleet.model import description as module

    desc = module.check(module.AgvDescription(serial=serial, manufacturer=manufacturer, interface=interface,
                                              name=f"{manufacturer} {serial}", skills=(), properties=()))
    return description_to_json(desc)


def description_to_json(description: Any) -> dict[str, Any]:
    """Plain JSON (lists, not tuples), so a description compares equal to its record on disk."""
    return json.loads(json.dumps(dataclasses.asdict(description)))


def description_from_json(data: dict[str, Any]) -> Any:
    from fleet.model import description as module

    props = tuple(module.AgvProperty(**p) for p in data.get("properties", ()))
    return module.AgvDescription(**{**data, "skills": tuple(data.get("skills", ())), "properties": props})


def renamed(description: Any, name: str | None) -> Any:
    return dataclasses.replace(description, name=name) if name else description


def binding_to_json(binding: Any) -> dict[str, Any]:
    return dataclasses.asdict(binding)


def binding_from_json(data: dict[str, Any]) -> Any:
    from fleet.model import binding as module

    return module.FleetBinding(**data)
