"""The paper's channels end to end, with real processes: the AGV middleware plant (like
ontology/examples/agv-middleware.ttl, generated here with free ports and the vehicle's id) applied
through two real agents — Mosquitto on 127.0.0.2, the context broker on 127.0.0.3, the mqtt-ngsi
bridge derived between them — and a simulated AGV (``python -m fleet.sim --interface paper``, a
process of its own) on Mosquitto.

An independent NGSI client, FiLiP's ``ContextBrokerClient``, plays the paper's task planner (its
JMeter test): it writes a motion item entity and then a wait action entity on the context broker
(the paper's "REST calls to the OCB" over motion_channel/action_channel); the context broker's
MQTT notifications bring them to the vehicle; the vehicle drives to the point and ends the task;
FiLiP, polling the status channel's entity, sees the task finished and the movement entity at the
point. Then bad items, one by one (wrong types, missing UUIDs, NaN and huge coordinates, a
polygon of two corners, an action before a motion in one task): each is refused with its reason
in the status entity and a log line of the vehicle, and a good task afterwards still runs.
SIGTERM: the status entity says OFFLINE; kill -9 of a second run: OFFLINE again, the last will. ``destroy`` and the agents' stop leave nothing behind.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import requests
from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import process
from engine.model import BridgeMechanism
from fleet.sim import map as site_map
from tests.integration.agents import ROOT, AgentFleet
from tests.integration.fleet_rig import agents_with_plant

filip_cb = pytest.importorskip("filip.clients.ngsi_v2")
from filip.models.base import FiwareHeader  # noqa: E402
from filip.models.ngsi_v2.context import ContextEntity  # noqa: E402

pytestmark = pytest.mark.integration

AGV = "paper-0001"
MQTT_IP, CB_IP = "127.0.0.2", "127.0.0.3"
STATUS_ENTITY = f"urn:ngsi-ld:AGV:{AGV}"
MOVEMENT_ENTITY = f"urn:ngsi-ld:AGVMovement:{AGV}"
DESCRIPTION_ENTITY = f"urn:ngsi-ld:AGVDescription:{AGV}"
MOTION_ENTITY = f"urn:ngsi-ld:Thing:{AGV}:motion_channel"  # minted by derive (docs/ontology.md)
ACTION_ENTITY = f"urn:ngsi-ld:Thing:{AGV}:action_channel"
START = site_map.default_map().parking()[0]
AREA = [[0, 0], [40, 0], [40, 20], [0, 20]]
DEADLINE = 60.0


def plant_text(mqtt_port: int, cb_port: int) -> str:
    """The agv-middleware example's structure for vehicle ``AGV``: its five channels on Mosquitto
    and on the context broker, status/movement/description each its own entity (one context broker
    cannot hold two topics as the same entity: the shapes refuse that)."""
    topics = {
        "status": ("publishes", STATUS_ENTITY, "AGV", 1, "true"),
        "movement": ("publishes", MOVEMENT_ENTITY, "AGVMovement", 0, "false"),
        "description": ("publishes", DESCRIPTION_ENTITY, "AGVDescription", 1, "true"),
        "motion": ("subscribes", None, None, 1, "false"),
        "action": ("subscribes", None, None, 1, "false"),
    }
    out = [
        "@prefix pk: <https://w3id.org/plantkg/ontology#> .",
        "@prefix p: <https://w3id.org/plantkg/tests/fleet-paper#> .",
        "@prefix owl: <http://www.w3.org/2002/07/owl#> .",
        "<https://w3id.org/plantkg/tests/fleet-paper> a owl:Ontology ; owl:imports <https://w3id.org/plantkg/ontology> .",
        'p:agv-interface a owl:NamedIndividual , pk:Resource ; pk:id "agv-interface" ; pk:name "AGV interface" ;',
        '    pk:isType p:agv-type ; pk:sendsTo p:fleet-mqtt ;',
        "    pk:publishes " + " , ".join(f"p:{t}" for t, v in topics.items() if v[0] == "publishes") + " ;",
        "    pk:subscribes " + " , ".join(f"p:{t}" for t, v in topics.items() if v[0] == "subscribes") + " .",
        'p:task-planner a owl:NamedIndividual , pk:Resource ; pk:id "task-planner" ; pk:name "Task planner" ;',
        '    pk:isType p:planner-type ; pk:sendsTo p:fleet-context ;',
        "    pk:subscribes " + " , ".join(f"p:{t}" for t, v in topics.items() if v[0] == "publishes") + " ;",
        "    pk:publishes " + " , ".join(f"p:{t}" for t, v in topics.items() if v[0] == "subscribes") + " .",
        'p:agv-type a owl:NamedIndividual , pk:ResourceType ; pk:id "agv-interface-type" ; pk:name "AGV interface" .',
        'p:planner-type a owl:NamedIndividual , pk:ResourceType ; pk:id "task-planner-type" ; pk:name "Task planner" .',
        f'p:fleet-mqtt a owl:NamedIndividual , pk:Broker ; pk:id "fleet-mqtt" ; pk:name "fleet-mqtt" ; pk:brokerType "mosquitto" ;',
        f'    pk:ip "{MQTT_IP}" ; pk:port {mqtt_port} ; pk:allowAnonymous true ; pk:hasTopic '  # the sim logs in as nobody
        + " , ".join(f"p:{t}" for t in topics) + " .",
        f'p:fleet-context a owl:NamedIndividual , pk:Broker ; pk:id "fleet-context" ; pk:name "fleet-context" ; pk:brokerType "ngsi-v2" ;',
        f'    pk:ip "{CB_IP}" ; pk:port {cb_port} ; pk:hasTopic ' + " , ".join(f"p:{t}" for t in topics) + " .",
    ]
    for name, (_, entity_id, entity_type, qos, retain) in topics.items():
        out.append(f'p:{name} a owl:NamedIndividual , pk:Topic ; pk:id "{name}-channel" ; pk:name "{AGV}/{name}_channel" ;')
        out.append(f'    pk:valueTopic "{name}" ; pk:typeTopic "json" ; pk:qos {qos} ; pk:retain {retain}'
                   + (f' ; pk:entityId "{entity_id}" ; pk:entityType "{entity_type}"' if entity_id else "") + " .")
    return "\n".join(out) + "\n"


def header() -> dict[str, Any]:
    return {"seq": 0, "stamp": "2026-11-24T20:00:00.000Z", "frame_id": "hall-1"}


def motion_item(task: str, sequence: int, point: list[float], **extra: Any) -> dict[str, Any]:
    return {"header": header(), "point_id": str(uuid.uuid4()), "task_id": task, "motion_id": str(uuid.uuid4()),
            "point": point, "max_velocity": [1.0, 0.0, 1.0], "max_acceleration": [0.5, 0.0, 1.0],
            "motion_area": AREA, "sequence": sequence, **extra}


def action_item(kind: str, task: str, sequence: int, **extra: Any) -> dict[str, Any]:
    return {"header": header(), "action_id": str(uuid.uuid4()), "task_id": task, "action": kind,
            "sequence": sequence, **extra}


NGSI_TYPE = {str: "Text", bool: "Boolean", int: "Number", float: "Number", type(None): "None"}


def entity(entity_id: str, item: dict[str, Any]) -> ContextEntity:
    """The item as an NGSI entity, one attribute per field (what FIROS did with ROS messages)."""
    attrs = {k: {"type": NGSI_TYPE.get(type(v), "StructuredValue"), "value": v} for k, v in item.items()}
    return ContextEntity(id=entity_id, type="Thing", **attrs)


class Planner:
    """The task planner's side: FiLiP against the context broker the agent runs."""

    def __init__(self, port: int, token: str) -> None:
        self.session = requests.Session()
        self.session.headers["Authorization"] = f"Bearer {token}"
        self.client = filip_cb.ContextBrokerClient(url=f"http://{CB_IP}:{port}", session=self.session,
                                                   fiware_header=FiwareHeader())

    def write(self, entity_id: str, item: dict[str, Any]) -> None:
        self.client.post_entity(entity(entity_id, item), update=True)  # create, or replace all attributes

    def read(self, entity_id: str) -> dict[str, Any] | None:
        try:
            found = self.client.get_entity(entity_id)
        except Exception:  # noqa: BLE001 - FiLiP raises its own HTTP error for 404: not there yet
            return None
        return {a.name: a.value for a in found.get_attributes()}

    def wait_status(self, predicate, what: str, child: process.Child | None) -> dict[str, Any]:
        return process.wait_until(lambda: (s := self.read(STATUS_ENTITY)) is not None and predicate(s) and s,
                                  DEADLINE, 0.1, what=what, child=child)

    def close(self) -> None:
        self.session.close()


@pytest.fixture
def plant(tmp_path: Path) -> Iterator[tuple[AgentFleet, Path]]:
    with agents_with_plant(tmp_path, plant_text, MQTT_IP, CB_IP) as made:
        yield made


def test_a_paper_agv_runs_a_task_written_on_the_context_broker(plant, tmp_path: Path, capsys) -> None:
    from engine.cli import main

    fleet, path = plant
    agents = ["--agents", str(fleet.agents_file)]
    assert main(["apply", str(path), *agents, "--yes"]) == 0, capsys.readouterr()
    [mqtt_port] = [b.spec.port for b in fleet.client(MQTT_IP).list_brokers()]
    [cb_port] = [b.spec.port for b in fleet.client(CB_IP).list_brokers()]
    process.wait_until(lambda: [b for b in fleet.client(MQTT_IP).list_bridges()
                                if b.spec.mechanism is BridgeMechanism.NGSI and b.status.value == "running"],
                       DEADLINE, 0.2, what="the mqtt-ngsi bridge running")
    sim = process.spawn([sys.executable, "-m", "fleet.sim", "--interface", "paper", "--broker", f"{MQTT_IP}:{mqtt_port}",
                         "--serial-prefix", "paper-", "--rate", "2", "--vmax", "1.5", "--amax", "1"],
                        log_dir=tmp_path, name="fleet-sim-paper", cwd=ROOT)
    planner = Planner(cb_port, fleet.agents[CB_IP].token)
    try:
        # the vehicle is there: its status and description are entities on the context broker
        status = planner.wait_status(lambda s: s.get("state") == "IDLE", "the vehicle's status IDLE", sim)
        assert (status["agv_id"], status["refused"], status["last_finished_sequence"]) == (AGV, 0, -1)
        description = process.wait_until(lambda: planner.read(DESCRIPTION_ENTITY), DEADLINE, 0.1,
                                         what="the description entity", child=sim)
        assert description["agv_id"] == AGV and "move" in description["skills"]

        # the paper's test: a point to reach, then a waiting action that ends the task
        task, goal = str(uuid.uuid4()), [START.x + 3.0, START.y + 2.0]
        motion = motion_item(task, 1, goal)
        began = time.monotonic()
        planner.write(MOTION_ENTITY, motion)
        planner.wait_status(lambda s: s.get("motion_id") == motion["motion_id"], "the motion running", sim)
        seen_running = time.monotonic() - began
        planner.write(ACTION_ENTITY, action_item("wait", task, 2, duration=0.5))
        status = planner.wait_status(lambda s: s.get("finished_task_id") == task, "the task finished", sim)
        print(f"\nmotion item written -> status entity shows it running: {seen_running * 1000:.0f} ms; "
              f"task of {((goal[0] - START.x) ** 2 + (goal[1] - START.y) ** 2) ** 0.5:.1f} m + 0.5 s wait "
              f"seen finished after {time.monotonic() - began:.1f} s")
        assert (status["state"], status["last_finished_sequence"], status["refused"]) == ("IDLE", 2, 0)
        pose = process.wait_until(
            lambda: (m := planner.read(MOVEMENT_ENTITY)) and abs(m["pose"]["x"] - goal[0]) < 0.01
            and abs(m["pose"]["y"] - goal[1]) < 0.01 and m["pose"], DEADLINE, 0.1, what="the movement at the goal", child=sim)
        assert pose

        # bad items, one by one: each refused with its reason in the status and a log line
        other = str(uuid.uuid4())
        bad: list[tuple[str, str, dict[str, Any] | bytes, str]] = [
            ("wrong types", MOTION_ENTITY, motion_item(str(uuid.uuid4()), 0, ["ten", 2.0]), "point/0 is `ten`"),
            ("missing task id", MOTION_ENTITY, {k: v for k, v in motion_item(str(uuid.uuid4()), 0, goal).items()
                                                if k != "task_id"}, "task_id: is required but missing"),
            ("missing motion id", MOTION_ENTITY, {k: v for k, v in motion_item(str(uuid.uuid4()), 0, goal).items()
                                                  if k != "motion_id"}, "motion_id: is required but missing"),
            ("huge coordinates", MOTION_ENTITY, motion_item(str(uuid.uuid4()), 0, [1e300, 2.0]), "greater than the maximum"),
            ("polygon of two corners", MOTION_ENTITY, motion_item(str(uuid.uuid4()), 0, goal, motion_area=[[0, 0], [40, 20]]),
             "motion_area is [[0, 0], [40, 20]]"),
            ("an action before a motion", ACTION_ENTITY, action_item("idle", other, 0, duration=0.1), ""),
            ("... the motion after it", MOTION_ENTITY, motion_item(other, 1, goal), "a motion after an action"),
            ("NaN (no JSON: bare on MQTT)", "", b'{"point": [NaN, 1.0]}', "NaN is not a JSON number"),
        ]
        refused = 0
        for label, entity_id, item, fragment in bad:
            if entity_id:
                planner.write(entity_id, item)  # type: ignore[arg-type]
            else:
                publish(mqtt_port, f"{AGV}/motion_channel", item)  # type: ignore[arg-type]
            if not fragment:
                continue  # accepted (an action of a new task)
            refused += 1
            status = planner.wait_status(lambda s, n=refused: s.get("refused") == n, f"refusal of {label}", sim)
            assert fragment in status["errors"][-1]["reason"], (label, status["errors"][-1])
        log = sim.log_path.read_text(encoding="utf-8")
        assert log.count("refused on motion_channel") == refused
        assert "Traceback" not in log

        # ... and the vehicle keeps working: the open task ends, a new one runs
        planner.write(ACTION_ENTITY, action_item("wait", other, 2, duration=0.1))
        planner.wait_status(lambda s: s.get("finished_task_id") == other, "the task with the refused motion ended", sim)
        again, back = str(uuid.uuid4()), [START.x, START.y]
        motion = motion_item(again, 0, back)
        planner.write(MOTION_ENTITY, motion)
        planner.wait_status(lambda s: s.get("motion_id") == motion["motion_id"], "the next motion running", sim)
        planner.write(ACTION_ENTITY, action_item("wait", again, 1, duration=0.1))
        status = planner.wait_status(lambda s: s.get("finished_task_id") == again, "the next task finished", sim)
        assert status["refused"] == refused

        assert process.stop(sim) == 0
        planner.wait_status(lambda s: s.get("state") == "OFFLINE", "OFFLINE after SIGTERM", None)
        # kill -9: the broker publishes the last will, status OFFLINE
        sim = process.spawn(sim.argv, log_dir=tmp_path, name="fleet-sim-paper-2", cwd=ROOT)
        planner.wait_status(lambda s: s.get("state") == "IDLE", "the vehicle back", sim)
        os.killpg(sim.pid, signal.SIGKILL)
        planner.wait_status(lambda s: s.get("state") == "OFFLINE", "OFFLINE as the last will after kill -9", None)
    finally:
        planner.close()
        process.stop(sim)
    assert main(["destroy", str(path), *agents, "--yes"]) == 0


def publish(port: int, topic: str, payload: bytes) -> None:
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"test-bare-{uuid.uuid4().hex[:8]}")
    client.connect(MQTT_IP, port)
    client.loop_start()
    try:
        client.publish(topic, payload, qos=1).wait_for_publish(10)
    finally:
        client.disconnect()
        client.loop_stop()
