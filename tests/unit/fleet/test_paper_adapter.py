"""The paper's VehicleLink without a broker: items handed to ``receive`` as MQTT would, the vehicle
stepped at a fixed tick; what it runs, what it refuses (with the reason in the status), and the
messages it would publish."""

from __future__ import annotations

import json
from typing import Any

import pytest

from fleet.paper import schemas
from fleet.paper.channels import Channel
from fleet.paper.messages import MachineState, Status
from fleet.sim import cli
from fleet.sim import map as site_map
from fleet.sim.mqtt_pump import MqttPump
from fleet.sim.paper_adapter import PaperLink, PaperLinkConfig, safe_text
from fleet.sim.vehicle import SimVehicle, VehicleSpec
from tests.unit.fleet.paper_cases import action, motion, uid

SITE = site_map.default_map()
START = SITE.parking()[0]
DT = 0.05


@pytest.fixture()
def link() -> PaperLink:
    return PaperLink(SimVehicle(VehicleSpec("plantkg", "agv-7", SITE, START)), PaperLinkConfig(), MqttPump())


def send(link: PaperLink, channel: Channel, message: Any) -> None:
    link.receive(channel, message if isinstance(message, bytes) else json.dumps(message).encode())


def run(link: PaperLink, until, limit: float = 60.0) -> tuple[float, float]:
    """Step until ``until()``; returns (seconds, the highest linear speed seen)."""
    t, top = 0.0, 0.0
    while not until():
        assert t < limit, link.status_fields()
        link.poll()
        link.vehicle.tick(DT)
        top = max(top, abs(link.vehicle.motion.v))
        t += DT
    return t, top


def test_a_task_drives_to_its_point_within_its_limits_and_ends_with_the_wait(link: PaperLink) -> None:
    task = uid()
    goal = [START.x + 4.0, START.y]
    send(link, Channel.MOTION, motion(task, 1, point=goal, max_velocity=[0.4, 0.0, 1.0]))
    send(link, Channel.ACTION, action("wait", task, 2, duration=1.0))
    link.poll()
    fields = link.status_fields()
    assert (fields["state"], fields["task_id"]) == (MachineState.MOVING, task)
    t, top = run(link, lambda: link.book.finished_task_id == task)
    pose = link.vehicle.motion.pose
    assert abs(pose.x - goal[0]) < 1e-6 and abs(pose.y - goal[1]) < 1e-6
    assert top <= 0.4 + 1e-9  # the item's limit, below the vehicle's 1 m/s
    assert t >= 4.0 / 0.4 + 1.0  # at least the cruise time plus the wait
    fields = link.status_fields()
    assert (fields["state"], fields["task_id"], fields["last_finished_sequence"], fields["refused"]) == (
        MachineState.IDLE, "", 2, 0)
    assert link.vehicle.spec.limits == VehicleSpec("plantkg", "agv-7", SITE, START).limits  # restored


def test_items_wrapped_in_a_context_broker_notification_run_too(link: PaperLink) -> None:
    task = uid()
    item = motion(task, 0, point=[START.x + 1.0, START.y])
    send(link, Channel.MOTION, {"subscriptionId": "5f1", "data": [{"id": "urn:ngsi-ld:Thing:agv-7:motion_channel",
                                                                  "type": "Thing", **item}]})
    send(link, Channel.ACTION, {"subscriptionId": "5f2", "data": [{"id": "a", "type": "Thing", **action("wait", task, 1)}]})
    run(link, lambda: link.book.finished_task_id == task)
    assert link.refused == 0


BAD_ITEMS: list[tuple[str, Channel, Any, str]] = [
    ("wrong type", Channel.MOTION, motion(point=["x", 1]), "point/0 = 'x'"),
    ("missing task id", Channel.MOTION, {k: v for k, v in motion().items() if k != "task_id"}, "task_id: is required but missing"),
    ("missing motion id", Channel.MOTION, {k: v for k, v in motion().items() if k != "motion_id"}, "motion_id"),
    ("NaN", Channel.MOTION, b'{"point": [NaN, 1]}', "NaN is not a JSON number"),
    ("huge", Channel.MOTION, motion(point=[1e300, 1.0]), "maximum"),
    ("outside the map", Channel.MOTION, motion(point=[60.0, 19.0], motion_area=[[0, 0], [100, 0], [100, 100]]), "outside map hall-1"),
    ("two-corner polygon", Channel.MOTION, motion(motion_area=[[0, 0], [40, 20]]), "motion_area"),
    ("not JSON", Channel.ACTION, b"load please", "not UTF-8 JSON"),
    ("unknown action", Channel.ACTION, action("dance"), "action = 'dance'"),
]


def test_bad_items_are_refused_one_by_one_and_the_vehicle_keeps_working(link: PaperLink, caplog) -> None:
    for _, channel, item, _ in BAD_ITEMS:
        send(link, channel, item)
    link.poll()
    fields = link.status_fields()
    assert fields["refused"] == len(BAD_ITEMS)
    reasons = [e.reason for e in fields["errors"]]
    assert len(reasons) == min(len(BAD_ITEMS), 10)
    for (label, channel, _, fragment), error in zip(BAD_ITEMS[-10:], fields["errors"], strict=True):
        assert error.channel == channel.value
        assert safe_text(fragment, 300) in error.reason, (label, error.reason)
    assert sum("refused on" in r.message for r in caplog.records) == len(BAD_ITEMS)
    assert fields["state"] is MachineState.IDLE and not link.vehicle.busy
    # the item ids of refused items with a readable id are named
    assert fields["errors"][-1].item_id
    task = uid()
    send(link, Channel.MOTION, motion(task, 0, point=[START.x + 1.0, START.y + 1.0]))
    send(link, Channel.ACTION, action("wait", task, 1))
    run(link, lambda: link.book.finished_task_id == task)


def test_an_action_followed_by_a_motion_in_one_task_is_refused(link: PaperLink) -> None:
    task = uid()
    send(link, Channel.ACTION, action("idle", task, 0, duration=0.2))
    send(link, Channel.MOTION, motion(task, 1))
    link.poll()
    assert link.refused == 1 and "a motion after an action" in link.status_fields()["errors"][0].reason
    send(link, Channel.ACTION, action("wait", task, 2, duration=0.2))
    run(link, lambda: link.book.finished_task_id == task)
    assert link.book.last_finished_sequence == 2


def test_load_unload_and_charging(link: PaperLink) -> None:
    task = uid()
    send(link, Channel.ACTION, action("load", task, 0, duration=0.5))
    send(link, Channel.ACTION, action("charge", task, 1))  # not on a charger: fails, the task goes on
    send(link, Channel.ACTION, action("wait", task, 2, duration=0.1))
    link.poll()
    assert link.status_fields()["state"] is MachineState.ACTING
    run(link, lambda: link.book.finished_task_id == task)
    assert link.vehicle.actions  # they ran on the executor
    [error] = link.status_fields()["errors"]
    assert error.channel == "action_channel" and "charge failed: not on a charger" in error.reason
    assert link.book.last_finished_sequence == 2
    charger = SITE.station("charger-1")
    task2 = uid()
    send(link, Channel.MOTION, motion(task2, 0, point=[charger.x, charger.y]))
    send(link, Channel.ACTION, action("charge", task2, 1))
    send(link, Channel.ACTION, action("wait", task2, 2, duration=0.1))
    run(link, lambda: link.book.finished_task_id == task2)
    assert link.status_fields()["state"] is MachineState.CHARGING
    task3 = uid()  # the next motion stops the charging first
    send(link, Channel.MOTION, motion(task3, 0, point=[charger.x + 2, charger.y]))
    send(link, Channel.ACTION, action("wait", task3, 1, duration=0.1))
    run(link, lambda: link.book.finished_task_id == task3)
    assert not link.vehicle.battery.charging and abs(link.vehicle.motion.pose.x - charger.x - 2) < 1e-6


def test_what_it_publishes_passes_the_schemas(link: PaperLink) -> None:
    description = link.description().to_json()
    assert schemas.check("description", description)["agv_id"] == "agv-7"
    assert set(description) == {"header", "agv_id", "name", "manufacturer", "skills", "physical"}
    assert {"move", "load", "unload", "wait", "charge"} <= set(description["skills"])
    send(link, Channel.MOTION, b"{")
    link.poll()
    status = Status(link.headers.next("status_channel"), **link.status_fields()).to_json()
    assert schemas.check("status", status)["refused"] == 1


def test_safe_text_removes_what_ngsi_refuses() -> None:
    assert safe_text("'a' (b) <c> = \"d\"; e=f", 100) == "`a` [b] lt cgt  is `d`, e:f"
    assert len(safe_text("x" * 500, 300)) == 300


def test_cli_builds_paper_links_and_refuses_a_long_agv_id(capsys) -> None:
    runner = cli.build(cli.parser().parse_args(["--interface", "paper", "--count", "2", "--serial-prefix", "p-"]))
    assert [type(link) for link in runner.links] == [PaperLink, PaperLink]
    assert runner.links[1].agv_id == "p-0002"
    assert cli.main(["--interface", "paper", "--serial-prefix", "x" * 70]) == 2
    assert "at most 64" in capsys.readouterr().err


class RecordingClient:
    """Stands in for the paho client after construction: connected, keeps what is published."""

    def __init__(self) -> None:
        self.sent: list[tuple[str, dict[str, Any], int, bool]] = []

    def is_connected(self) -> bool:
        return True

    def publish(self, topic: str, payload: bytes, qos: int, retain: bool) -> None:
        self.sent.append((topic, json.loads(payload), qos, retain))


def test_the_last_will_is_a_retained_offline_status(link: PaperLink) -> None:
    client = link.client
    assert (client._will_topic, client._will_qos, client._will_retain) == (b"agv-7/status_channel", 1, True)
    will = schemas.decode("status", client._will_payload)[0]
    assert (will["agv_id"], will["state"]) == ("agv-7", "OFFLINE")


def test_status_on_change_and_heartbeat_movement_at_its_rate(link: PaperLink) -> None:
    from fleet.sim.vehicle import Outbox

    link.config = PaperLinkConfig(movement_interval=0.5, status_interval=10.0)
    client = link.client = RecordingClient()  # type: ignore[assignment]
    now = 100.0
    link.publish(Outbox(), now)
    task = uid()
    send(link, Channel.MOTION, motion(task, 0, point=[START.x + 1.0, START.y]))
    send(link, Channel.ACTION, action("wait", task, 1, duration=0.2))
    for _ in range(int(8 / DT)):  # 8 s
        link.poll()
        link.vehicle.tick(DT)
        now += DT
        link.publish(Outbox(), now)
    by_channel: dict[str, list[tuple[dict[str, Any], int, bool]]] = {}
    for topic, message, qos, retain in client.sent:
        by_channel.setdefault(topic.split("/")[1], []).append((message, qos, retain))
    assert {(q, r) for _, q, r in by_channel["status_channel"]} == {(1, True)}
    assert {(q, r) for _, q, r in by_channel["movement_channel"]} == {(0, False)}
    assert 16 <= len(by_channel["movement_channel"]) <= 17  # 8 s at 2 Hz
    states = [m["state"] for m, _, _ in by_channel["status_channel"]]
    assert states[0] == "IDLE" and "MOVING" in states and "ACTING" in states and states[-1] == "IDLE"
    assert len(states) < 40  # on change (and the battery's tenths), not every tick
    assert [m["header"]["seq"] for m, _, _ in by_channel["status_channel"]] == list(range(1, len(states) + 1))
    for message, _, _ in by_channel["status_channel"] + by_channel["movement_channel"]:
        schemas.check("status" if "state" in message else "movement", message)
    count = len(states)
    link.publish(Outbox(), now + 10.0)  # nothing changed: the heartbeat
    assert len([t for t, *_ in client.sent if t.endswith("status_channel")]) == count + 1
