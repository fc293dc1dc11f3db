"""The paper's channel names, topic helpers and MQTT rules."""

from __future__ import annotations

import pytest

from fleet.paper import channels
from fleet.paper.channels import Channel
from fleet.paper.errors import ChannelError


def test_topics_and_their_parse() -> None:
    for channel in Channel:
        name = channels.topic("agv-7", channel)
        assert name == f"agv-7/{channel.value}"
        assert channels.parse(name) == ("agv-7", channel)


def test_the_five_channels_and_their_directions() -> None:
    assert sorted(c.value for c in Channel) == ["action_channel", "description_channel", "motion_channel",
                                                "movement_channel", "status_channel"]
    assert {c for c in Channel if c.to_vehicle} == {Channel.ACTION, Channel.MOTION}


@pytest.mark.parametrize(("channel", "qos", "retain"), [
    ("motion_channel", 1, False), ("action_channel", 1, False), ("movement_channel", 0, False),
    ("status_channel", 1, True), ("description_channel", 1, True),
])
def test_mqtt_rules(channel: str, qos: int, retain: bool) -> None:
    assert channels.rule(channel) == channels.MqttRule(qos, retain)


@pytest.mark.parametrize(("agv_id", "fragment"), [
    ("", "non-empty"),
    ("a/b", "character '/' at position 1"),
    ("ab+", "character '+' at position 2"),
    ("#", "character '#' at position 0"),
    ("agv 7", "character ' ' at position 3"),
    ("x" * 65, "65 characters, at most 64"),
])
def test_bad_agv_ids_are_named(agv_id: str, fragment: str) -> None:
    with pytest.raises(ChannelError) as caught:
        channels.topic(agv_id, Channel.STATUS)
    assert fragment in str(caught.value) and caught.value.field == "agv_id"


@pytest.mark.parametrize(("topic", "fragment"), [
    ("agv-7", "1 levels, expected 2"),
    ("a/b/status_channel", "3 levels"),
    ("agv-7/state", "unknown channel 'state'"),
    ("a$b/status_channel", "character '$'"),
])
def test_bad_topics_are_named(topic: str, fragment: str) -> None:
    with pytest.raises(ChannelError, match=None) as caught:
        channels.parse(topic)
    assert fragment in str(caught.value)


def test_agv_ids_take_the_vda5050_serial_characters() -> None:
    assert channels.check_agv_id("A-z_0.9:x") == "A-z_0.9:x"
    assert channels.check_agv_id("x" * 64) == "x" * 64
