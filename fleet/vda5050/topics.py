"""VDA 5050 2.1 topic names and the MQTT rules of each topic.

Topic layout (VDA 5050 2.1, section 6.5): ``interfaceName/majorVersion/manufacturer/serialNumber/topic``,
here ``uagv/v2/<manufacturer>/<serial>/<topic>``. A level must not contain the MQTT separators or
wildcards ``/ + #`` nor ``$`` (reserved for broker topics); serial numbers are restricted to
``A-Z a-z 0-9 _ . : -``. Errors name the bad character and its position, because "invalid topic"
alone is what users of such systems complain about.

QoS and retain per topic: ``connection`` is QoS 1, retained, and is also the last will
(``CONNECTIONBROKEN``); every other topic is QoS 0, not retained. (The standard allows a vendor to
retain ``factsheet``; we do not, so a factsheet is always an answer to ``factsheetRequest``.)
"""

from __future__ import annotations

import enum
import re
from dataclasses import dataclass

from fleet.vda5050.errors import TopicError

INTERFACE_NAME = "uagv"
MAJOR_VERSION = "v2"
FORBIDDEN_IN_LEVEL = "/+#$"
SERIAL_PATTERN = re.compile(r"[A-Za-z0-9_.:\-]+")
MAX_LEVEL_LENGTH = 128


class Subtopic(str, enum.Enum):
    """The six VDA 5050 topics of one vehicle, with who publishes them."""

    ORDER = "order"
    INSTANT_ACTIONS = "instantActions"
    STATE = "state"
    VISUALIZATION = "visualization"
    CONNECTION = "connection"
    FACTSHEET = "factsheet"

    @property
    def from_master(self) -> bool:
        return self in (Subtopic.ORDER, Subtopic.INSTANT_ACTIONS)


@dataclass(frozen=True)
class MqttRule:
    qos: int
    retain: bool


RULES: dict[Subtopic, MqttRule] = {
    Subtopic.ORDER: MqttRule(qos=0, retain=False),
    Subtopic.INSTANT_ACTIONS: MqttRule(qos=0, retain=False),
    Subtopic.STATE: MqttRule(qos=0, retain=False),
    Subtopic.VISUALIZATION: MqttRule(qos=0, retain=False),
    Subtopic.CONNECTION: MqttRule(qos=1, retain=True),
    Subtopic.FACTSHEET: MqttRule(qos=0, retain=False),
}


def rule(subtopic: Subtopic | str) -> MqttRule:
    return RULES[Subtopic(subtopic)]


def check_level(field: str, value: str) -> str:
    """Return ``value`` if it can be a topic level; else raise :class:`TopicError` naming the char."""
    if not isinstance(value, str) or not value:
        raise TopicError(field, str(value), "must be a non-empty string")
    if len(value) > MAX_LEVEL_LENGTH:
        raise TopicError(field, value[:40] + "...", f"is {len(value)} characters, at most {MAX_LEVEL_LENGTH}")
    for position, char in enumerate(value):
        if char in FORBIDDEN_IN_LEVEL:
            raise TopicError(field, value, f"character {char!r} at position {position} is not allowed in a topic level")
        if not char.isprintable():
            raise TopicError(field, value, f"non-printable character {char!r} at position {position}")
    return value


def check_serial(serial: str) -> str:
    """A serial number: a topic level made only of ``A-Z a-z 0-9 _ . : -``."""
    check_level("serialNumber", serial)
    for position, char in enumerate(serial):
        if not SERIAL_PATTERN.fullmatch(char):
            raise TopicError("serialNumber", serial, f"character {char!r} at position {position} is not one of A-Z a-z 0-9 _ . : -")
    return serial


def topic(manufacturer: str, serial: str, subtopic: Subtopic | str) -> str:
    """The full topic of one vehicle's ``subtopic``, after checking both levels."""
    check_level("manufacturer", manufacturer)
    check_serial(serial)
    return f"{INTERFACE_NAME}/{MAJOR_VERSION}/{manufacturer}/{serial}/{Subtopic(subtopic).value}"


def subscription(subtopic: Subtopic | str, manufacturer: str = "+", serial: str = "+") -> str:
    """A subscription filter; ``+`` (the default) matches every manufacturer / serial number."""
    if manufacturer != "+":
        check_level("manufacturer", manufacturer)
    if serial != "+":
        check_serial(serial)
    return f"{INTERFACE_NAME}/{MAJOR_VERSION}/{manufacturer}/{serial}/{Subtopic(subtopic).value}"


@dataclass(frozen=True)
class VehicleTopic:
    manufacturer: str
    serial: str
    subtopic: Subtopic


def parse(name: str) -> VehicleTopic:
    """Split a received topic into its parts; :class:`TopicError` says which level is wrong."""
    parts = name.split("/")
    if len(parts) != 5:
        raise TopicError("topic", name, f"has {len(parts)} levels, a VDA 5050 topic has 5 (uagv/v2/manufacturer/serial/topic)")
    interface, major, manufacturer, serial, sub = parts
    if interface != INTERFACE_NAME:
        raise TopicError("topic", name, f"interface name {interface!r} is not {INTERFACE_NAME!r}")
    if major != MAJOR_VERSION:
        raise TopicError("topic", name, f"major version {major!r} is not {MAJOR_VERSION!r}")
    try:
        kind = Subtopic(sub)
    except ValueError:
        known = ", ".join(s.value for s in Subtopic)
        raise TopicError("topic", name, f"last level {sub!r} is not one of {known}") from None
    return VehicleTopic(check_level("manufacturer", manufacturer), check_serial(serial), kind)
