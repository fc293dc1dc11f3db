"""What a vehicle says about itself, as one frozen :class:`AgvDescription`.

Two sources, both checked whole before anything else happens (so a bad one changes nothing):

- :func:`from_factsheet`: a VDA 5050 2.x factsheet (the answer to ``factsheetRequest`` on
  ``uagv/v2/<manufacturer>/<serial>/factsheet``). Read: ``typeSpecification.seriesName`` and
  ``maxLoadMass``, ``physicalParameters`` (``speedMax``, ``accelerationMax``, ``heightMax``,
  ``width``, ``length``; optional ``speedMin``, ``decelerationMax`` and the simulator's extension
  ``angularSpeedMax`` / ``angularAccelerationMax``), ``protocolFeatures.agvActions[].actionType``
  (the skills). These are fields the standard's schema requires; everything else is ignored.
- :func:`from_paper_description`: the paper's ``description_channel`` payload (docs/fleet.md):
  ``agv_id``, ``name``, ``manufacturer``, ``skills``, ``physical`` (``max_velocity`` and
  ``max_acceleration`` per axis x, y, theta; ``payload_kg``; optional ``battery_capacity_wh``;
  ``footprint.length`` / ``width``).

A skill is a VDA 5050 actionType or a paper skill name, plus ``move`` for any vehicle that drives
(a maximum speed above 0). Properties are SI values with their XSD type (all ``decimal``). Errors
are :class:`~fleet.model.errors.DescriptionError` naming the field path and the value.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

from fleet.model import values
from fleet.model.errors import DescriptionError

INTERFACES = ("vda5050", "paper-channels")
_DECIMAL = re.compile(r"[+-]?([0-9]+([.][0-9]*)?|[.][0-9]+)")
MOVE = "move"


@dataclass(frozen=True)
class AgvProperty:
    """One physical datum: ``id`` is short and unique per vehicle (``max-speed``), ``value`` the
    lexical form of an XSD ``value_type`` (its local name: ``decimal``, ``string``, ...)."""

    id: str
    name: str
    value: str
    value_type: str


@dataclass(frozen=True)
class AgvDescription:
    """A vehicle as the graph needs it (see the module docstring)."""

    serial: str
    manufacturer: str
    interface: str
    name: str
    skills: tuple[str, ...]
    properties: tuple[AgvProperty, ...]


def from_factsheet(manufacturer: str, serial: str, payload: dict[str, Any]) -> AgvDescription:
    """The description in a VDA 5050 factsheet published under ``manufacturer`` / ``serial``."""
    manufacturer = values.manufacturer("manufacturer", manufacturer)
    serial = values.serial("serialNumber", serial)
    data = values.payload("factsheet", payload)
    for key, expected in (("manufacturer", manufacturer), ("serialNumber", serial)):
        if key in data and data[key] != expected:
            raise DescriptionError(key, data[key], f"the factsheet names another vehicle than its topic ({expected!r})")
    spec = values.obj("typeSpecification", values.member(data, "typeSpecification", "typeSpecification"))
    phys = values.obj("physicalParameters", values.member(data, "physicalParameters", "physicalParameters"))
    features = values.obj("protocolFeatures", values.member(data, "protocolFeatures", "protocolFeatures"))

    def num(parent: dict[str, Any], where: str, key: str, *, optional: bool = False, positive: bool = False) -> float | None:
        path = f"{where}.{key}"
        if optional and parent.get(key) is None:
            return None
        return values.number(path, values.member(parent, key, path), positive=positive)

    series = values.name("typeSpecification.seriesName", values.member(spec, "seriesName", "typeSpecification.seriesName"))
    load = num(spec, "typeSpecification", "maxLoadMass")
    speed = num(phys, "physicalParameters", "speedMax")
    found = {
        "max-speed": speed,
        "min-speed": num(phys, "physicalParameters", "speedMin", optional=True),
        "max-acceleration": num(phys, "physicalParameters", "accelerationMax"),
        "max-deceleration": num(phys, "physicalParameters", "decelerationMax", optional=True),
        "max-angular-speed": num(phys, "physicalParameters", "angularSpeedMax", optional=True),
        "max-angular-acceleration": num(phys, "physicalParameters", "angularAccelerationMax", optional=True),
        "max-load-mass": load,
        "length": num(phys, "physicalParameters", "length", positive=True),
        "width": num(phys, "physicalParameters", "width", positive=True),
        "height": num(phys, "physicalParameters", "heightMax", positive=True),
    }
    actions = values.member(features, "agvActions", "protocolFeatures.agvActions")
    if not isinstance(actions, list):
        raise DescriptionError("protocolFeatures.agvActions", actions, "must be a JSON array")
    if len(actions) > values.MAX_SKILLS:
        raise DescriptionError("protocolFeatures.agvActions", f"<{len(actions)} actions>",
                               f"more than {values.MAX_SKILLS} actions")
    skills = []
    for i, action in enumerate(actions):
        where = f"protocolFeatures.agvActions[{i}]"
        action = values.obj(where, action)
        skills.append(values.skill(f"{where}.actionType", values.member(action, "actionType", f"{where}.actionType")))
    return AgvDescription(serial=serial, manufacturer=manufacturer, interface="vda5050",
                          name=values.name("typeSpecification.seriesName", f"{series} {serial}"[:values.MAX_NAME]),
                          skills=_skills(skills, speed or 0.0), properties=_properties(found))


def from_paper_description(payload: dict[str, Any]) -> AgvDescription:
    """The description a paper-channel vehicle publishes on ``<agv-id>/description_channel``."""
    data = values.payload("description", payload)
    serial = values.serial("agv_id", values.member(data, "agv_id", "agv_id"))
    name = values.name("name", values.member(data, "name", "name"))
    manufacturer = values.manufacturer("manufacturer", values.member(data, "manufacturer", "manufacturer"))
    raw_skills = values.member(data, "skills", "skills")
    if not isinstance(raw_skills, list):
        raise DescriptionError("skills", raw_skills, "must be a JSON array of skill names")
    if len(raw_skills) > values.MAX_SKILLS:
        raise DescriptionError("skills", f"<{len(raw_skills)} skills>", f"more than {values.MAX_SKILLS} skills")
    skills = [values.skill(f"skills[{i}]", s) for i, s in enumerate(raw_skills)]
    phys = values.obj("physical", values.member(data, "physical", "physical"))

    def axes(key: str) -> tuple[float, float, float]:
        path = f"physical.{key}"
        raw = values.member(phys, key, path)
        if not isinstance(raw, list) or len(raw) != 3:
            raise DescriptionError(path, raw, "must be a JSON array of 3 numbers (x, y, theta)")
        return tuple(values.number(f"{path}[{i}]", v) for i, v in enumerate(raw))  # type: ignore[return-value]

    velocity, acceleration = axes("max_velocity"), axes("max_acceleration")
    payload_kg = values.number("physical.payload_kg", values.member(phys, "payload_kg", "physical.payload_kg"))
    capacity = phys.get("battery_capacity_wh")
    footprint = values.obj("physical.footprint", values.member(phys, "footprint", "physical.footprint"))
    found = {
        "max-speed": velocity[0], "max-lateral-speed": velocity[1], "max-angular-speed": velocity[2],
        "max-acceleration": acceleration[0], "max-lateral-acceleration": acceleration[1],
        "max-angular-acceleration": acceleration[2],
        "max-load-mass": payload_kg,
        "battery-capacity": None if capacity is None else values.number("physical.battery_capacity_wh", capacity),
        "length": values.number("physical.footprint.length",
                                values.member(footprint, "length", "physical.footprint.length"), positive=True),
        "width": values.number("physical.footprint.width",
                               values.member(footprint, "width", "physical.footprint.width"), positive=True),
    }
    return AgvDescription(serial=serial, manufacturer=manufacturer, interface="paper-channels", name=name,
                          skills=_skills(skills, max(velocity[0], velocity[1])), properties=_properties(found))


#: Property id -> its name (with the unit) in the graph.
PROPERTY_NAMES = {
    "max-speed": "Maximum speed (m/s)",
    "min-speed": "Minimum speed (m/s)",
    "max-lateral-speed": "Maximum lateral speed (m/s)",
    "max-angular-speed": "Maximum angular speed (rad/s)",
    "max-acceleration": "Maximum acceleration (m/s2)",
    "max-deceleration": "Maximum deceleration (m/s2)",
    "max-lateral-acceleration": "Maximum lateral acceleration (m/s2)",
    "max-angular-acceleration": "Maximum angular acceleration (rad/s2)",
    "max-load-mass": "Maximum load mass (kg)",
    "battery-capacity": "Battery capacity (Wh)",
    "length": "Length (m)",
    "width": "Width (m)",
    "height": "Height (m)",
}


def _properties(found: dict[str, float | None]) -> tuple[AgvProperty, ...]:
    return tuple(AgvProperty(key, PROPERTY_NAMES[key], values.decimal_text(value), "decimal")
                 for key, value in found.items() if value is not None)


def _skills(names: list[str], speed: float) -> tuple[str, ...]:
    out = set(names)
    if speed > 0:
        out.add(MOVE)
    return tuple(sorted(out))


def check(desc: AgvDescription) -> AgvDescription:
    """``desc`` checked again field by field (it may come from a stored record, not a parser)."""
    if not isinstance(desc, AgvDescription):
        raise DescriptionError("description", desc, "must be an AgvDescription")
    values.serial("serial", desc.serial)
    values.manufacturer("manufacturer", desc.manufacturer)
    if desc.interface not in INTERFACES:
        raise DescriptionError("interface", desc.interface, f"must be one of {', '.join(INTERFACES)}")
    values.name("name", desc.name)
    if not isinstance(desc.skills, tuple) or len(desc.skills) > values.MAX_SKILLS:
        raise DescriptionError("skills", desc.skills, f"must be a tuple of at most {values.MAX_SKILLS} skill names")
    for i, s in enumerate(desc.skills):
        values.skill(f"skills[{i}]", s)
    if not isinstance(desc.properties, tuple):
        raise DescriptionError("properties", desc.properties, "must be a tuple of AgvProperty")
    seen: set[str] = set()
    for i, p in enumerate(desc.properties):
        if not isinstance(p, AgvProperty):
            raise DescriptionError(f"properties[{i}]", p, "must be an AgvProperty")
        values.skill(f"properties[{i}].id", p.id)
        if p.id in seen:
            raise DescriptionError(f"properties[{i}].id", p.id, "is used by another property of the vehicle")
        seen.add(p.id)
        values.name(f"properties[{i}].name", p.name)
        if p.value_type not in VALUE_TYPES or not VALUE_TYPES[p.value_type](p.value):
            raise DescriptionError(f"properties[{i}].value", p.value,
                                   f"is not a valid {p.value_type!r} (value types: {', '.join(VALUE_TYPES)})")
    return desc


def _is_decimal(text: object) -> bool:
    return isinstance(text, str) and _DECIMAL.fullmatch(text) is not None


def _is_text(text: object) -> bool:
    if not isinstance(text, str):
        return False
    try:
        values.name("value", text)
    except DescriptionError:
        return False
    return True


#: The value types a stored property may have, with a check of its lexical form.
VALUE_TYPES = {"decimal": _is_decimal, "string": _is_text}
