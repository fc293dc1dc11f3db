"""The paper's five channels of one vehicle: topic names ``<agv-id>/<channel>`` and their MQTT rules.

The vehicle subscribes to ``motion_channel`` and ``action_channel`` and publishes
``movement_channel``, ``status_channel`` and ``description_channel`` (section 4.3 of the paper).
MQTT rules, ours (the paper used ROS topics and says nothing of QoS): commands are QoS 1 (a lost
motion item would leave a task stuck), not retained (an old command must not run again when the
vehicle reconnects); ``status`` and ``description`` are QoS 1 and retained, so a late subscriber
(plug and play) sees the vehicle at once, and ``status`` = OFFLINE is the vehicle's last will;
``movement`` is QoS 0, not retained (periodic, the next one replaces a lost one).

An agv id obeys VDA 5050's serial-number characters (``A-Z a-z 0-9 _ . : -``, at most 64), so it
is also one safe topic level; errors name the character and its position.
"""

from __future__ import annotations

import enum
import re
from dataclasses import dataclass

from fleet.paper.errors import ChannelError

AGV_ID_PATTERN = re.compile(r"[A-Za-z0-9_.:\-]{1,64}")
MAX_AGV_ID = 64


class Channel(str, enum.Enum):
    ACTION = "action_channel"
    MOTION = "motion_channel"
    MOVEMENT = "movement_channel"
    STATUS = "status_channel"
    DESCRIPTION = "description_channel"

    @property
    def to_vehicle(self) -> bool:
        return self in (Channel.ACTION, Channel.MOTION)


@dataclass(frozen=True)
class MqttRule:
    qos: int
    retain: bool


RULES: dict[Channel, MqttRule] = {
    Channel.ACTION: MqttRule(1, False),
    Channel.MOTION: MqttRule(1, False),
    Channel.MOVEMENT: MqttRule(0, False),
    Channel.STATUS: MqttRule(1, True),
    Channel.DESCRIPTION: MqttRule(1, True),
}


def rule(channel: Channel | str) -> MqttRule:
    return RULES[Channel(channel)]


def check_agv_id(agv_id: str) -> str:
    """Return ``agv_id`` if usable as the first topic level, else raise naming the character."""
    if not isinstance(agv_id, str) or not agv_id:
        raise ChannelError("agv_id", str(agv_id), "must be a non-empty string")
    if len(agv_id) > MAX_AGV_ID:
        raise ChannelError("agv_id", agv_id, f"{len(agv_id)} characters, at most {MAX_AGV_ID}")
    for position, char in enumerate(agv_id):
        if not AGV_ID_PATTERN.fullmatch(char):
            raise ChannelError("agv_id", agv_id, f"character {char!r} at position {position} is not allowed")
    return agv_id


def topic(agv_id: str, channel: Channel | str) -> str:
    return f"{check_agv_id(agv_id)}/{Channel(channel).value}"


def parse(name: str) -> tuple[str, Channel]:
    """Split ``<agv-id>/<channel>``; raise :class:`ChannelError` naming the wrong part."""
    parts = name.split("/")
    if len(parts) != 2:
        raise ChannelError("topic", name, f"{len(parts)} levels, expected 2 (<agv-id>/<channel>)")
    agv_id, last = parts
    check_agv_id(agv_id)
    try:
        return agv_id, Channel(last)
    except ValueError:
        known = ", ".join(c.value for c in Channel)
        raise ChannelError("topic", name, f"unknown channel {last!r}; one of {known}") from None
