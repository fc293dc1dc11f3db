"""``plantkg status`` flags a bridge whose forwarded rate runs away (issue 15), with real parts.

Two ``plantkg agent`` processes serve 127.0.0.2 (Mosquitto) and 127.0.0.3 (Kafka); the plant is a
copy of ontology/examples/robot-cell.ttl with free ports, so the Mosquitto agent runs a real
MQTT -> Kafka bridge worker. A publisher sends a few hundred messages/s to the bridged topic; the
worker's ``forwarded_per_s`` reaches status through its agent: ``--max-bridge-rate 50`` exits 2
naming the bridge, the default limit (10,000/s) exits 0. Waits poll with deadlines.
"""

from __future__ import annotations

import json
import os
import threading
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import process
from engine.cli import main
from engine.model import BridgeStatus
from tests.integration.agents import AgentFleet, plant_copy, start_agents

pytestmark = pytest.mark.integration

MQTT_HOST, KAFKA_HOST = "127.0.0.2", "127.0.0.3"
POSITION = "robot.abb-irb120.position"  # the topic the robot cell bridges from Mosquitto into Kafka
BRIDGE = "bridge.mosquitto.kafka"
RATE = 300.0  # messages/s the publisher aims at: far above 50, far below the default 10,000


@dataclass
class Cell:
    fleet: AgentFleet
    plant: Path
    ports: dict[str, int]

    def status(self, capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
        code = main(["status", str(self.plant), "--agents", str(self.fleet.agents_file), *args])
        out = capsys.readouterr()
        return code, out.out, out.err


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cell]:
    tmp = tmp_path_factory.mktemp("status-rate")
    fleet = start_agents([MQTT_HOST, KAFKA_HOST], tmp)
    try:
        plant, ports = plant_copy("robot-cell.ttl", tmp)
        assert main(["apply", str(plant), "--agents", str(fleet.agents_file), "--yes"]) == 0
        agent = fleet.client(MQTT_HOST)
        process.wait_until(lambda: [b for b in agent.list_bridges() if b.status is BridgeStatus.RUNNING],
                           60.0, 0.2, what="the Mosquitto -> Kafka bridge running")
        fleet.brokers()  # remember the broker pids for the final check
        fleet.broker_pids |= {b.pid for b in agent.list_bridges() if b.pid}  # and the worker's
        yield Cell(fleet, plant, ports)
        assert main(["destroy", str(plant), "--agents", str(fleet.agents_file), "--yes"]) == 0
    finally:
        fleet.stop()


@dataclass
class Publisher:
    """Publishes to ``POSITION`` at about ``RATE`` messages/s in a thread until stopped."""

    port: int
    stop: threading.Event = field(default_factory=threading.Event)
    sent: int = 0

    def run(self) -> None:
        client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"it-rate-{uuid.uuid4().hex[:8]}")
        # the robot cell's Mosquitto is closed: publish as the ROS machine (tests/conftest.py
        # made its throwaway password, which the agents inherit)
        client.username_pw_set("ros-machine", os.environ["PLANTKG_ROS_MACHINE_PASSWORD"])
        client.connect(MQTT_HOST, self.port)
        client.loop_start()
        try:
            process.wait_until(client.is_connected, 10.0, 0.01, what="MQTT CONNACK")
            batch = 10  # messages per pause of 1/30 s: ~300/s without a timer per message
            while not self.stop.is_set():
                for _ in range(batch):
                    client.publish(POSITION, b'{"joints_deg": [1, 2, 3, 4, 5, 6]}', qos=0)
                self.sent += batch
                self.stop.wait(batch / RATE)  # pacing, ends at once on stop
        finally:
            client.disconnect()
            client.loop_stop()


@pytest.fixture
def flood(cell: Cell) -> Iterator[Publisher]:
    publisher = Publisher(cell.ports["mosquitto"])
    thread = threading.Thread(target=publisher.run, name="rate-publisher", daemon=True)
    thread.start()
    try:
        process.wait_until(lambda: publisher.sent > 0, 15.0, 0.05, what="the publisher sending")
        yield publisher
    finally:
        publisher.stop.set()
        thread.join(20)
        assert not thread.is_alive()


def _bridge_rate(cell: Cell, capsys: pytest.CaptureFixture[str]) -> float | None:
    code, out, err = cell.status(capsys, "--format", "json")
    assert code in (0, 2), out + err
    [bridge] = [b for b in json.loads(out)["bridges"] if b["bridge"] == BRIDGE]
    return bridge["forwarded_per_s"]


def test_a_quiet_bridge_has_a_rate_of_zero_and_status_converges(cell: Cell, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = cell.status(capsys, "--max-bridge-rate", "50")
    assert code == 0, out + err
    header, row = [line for line in out.splitlines() if "BRIDGE" in line or line.startswith(BRIDGE)]
    assert "RATE/S" in header.split()
    rate_cell = row.split()[header.split().index("RATE/S")]
    assert float(rate_cell) < 50 and "warning" not in err


def test_a_flooded_bridge_is_named_and_status_exits_2(cell: Cell, flood: Publisher,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    # the worker's 10 s window fills as the flood goes on: wait until the bridge is above 50/s
    rate = process.wait_until(lambda: (r := _bridge_rate(cell, capsys)) is not None and r > 100 and r,
                              30.0, 0.5, what="the bridge forwarding more than 100 messages/s")
    with capsys.disabled():  # the figure, for a run with -s
        print(f"\nbridge rate seen by status: {rate} messages/s (the publisher aims at {RATE})")
    assert rate < 10 * RATE  # a measured rate, not a counter

    code, out, err = cell.status(capsys, "--max-bridge-rate", "50")
    assert code == 2, out + err
    assert f"warning: bridge {BRIDGE} forwards " in err and "above the limit of 50.0" in err
    assert "loop through a bridge set up outside the plant" in err and "publisher flooding" in err

    code, out, err = cell.status(capsys, "--max-bridge-rate", "50", "--format", "json")
    answer = json.loads(out)
    assert code == 2 and answer["converged"] is False
    assert [r["bridge"] for r in answer["runaway_bridges"]] == [BRIDGE]

    code, out, err = cell.status(capsys)  # the default limit: a few hundred messages/s is fine
    assert code == 0, out + err
    assert "warning" not in err
