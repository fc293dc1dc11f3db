"""The paper's simulation test (its Fig. 7), real processes: two AGVs on the paper's channels, each
given an ordered set of target points and a wait action through REST calls to the context
broker, no task planner in between.

The plant is the AGV middleware of tests/integration/test_fleet_paper.py for two vehicles
(``fig7-0001``, ``fig7-0002``: their five channels on Mosquitto 127.0.0.2 and the context broker
127.0.0.3, the mqtt-ngsi bridge derived between them), applied through two real agents; the two
vehicles are one ``python -m fleet.sim --interface paper --count 2`` process. FiLiP writes each
vehicle's motion items (one per point, rising sequence) on its motion entity, and once the
vehicle runs the first one, the wait action on its action entity. An independent NGSI client
(plain HTTP, the paper's JMeter) polls both status entities every 50 ms and records what it sees:
each vehicle's motions run in the order given (never one before an earlier one), the task ends
(``finished_task_id``, ``last_finished_sequence`` the wait's), nothing refused, and the movement
entity stands at the last point. The time from the first write to the completion seen by the
poller is printed for each vehicle.
"""

from __future__ import annotations

import json
import math
import sys
import threading
import time
import urllib.error
import urllib.request
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from engine import process
from engine.model import BridgeMechanism
from fleet.sim import map as site_map
from tests.integration.agents import ROOT, AgentFleet
from tests.integration.fleet_rig import agents_with_plant

filip_cb = pytest.importorskip("filip.clients.ngsi_v2")
import requests  # noqa: E402
from filip.models.base import FiwareHeader  # noqa: E402
from filip.models.ngsi_v2.context import ContextEntity  # noqa: E402

pytestmark = pytest.mark.integration

MQTT_IP, CB_IP = "127.0.0.2", "127.0.0.3"
AGVS = ("fig7-0001", "fig7-0002")
AREA = [[0, 0], [40, 0], [40, 20], [0, 20]]
DEADLINE = 90.0
PARK = site_map.default_map().parking()
# each vehicle's ordered target points: a small loop away from its parking spot and back
POINTS = {
    AGVS[0]: [[PARK[0].x - 3.0, PARK[0].y], [PARK[0].x - 3.0, PARK[0].y + 4.0], [PARK[0].x, PARK[0].y + 4.0]],
    AGVS[1]: [[PARK[1].x + 3.0, PARK[1].y], [PARK[1].x + 3.0, PARK[1].y + 4.0], [PARK[1].x, PARK[1].y + 4.0]],
}
NGSI_TYPE = {str: "Text", bool: "Boolean", int: "Number", float: "Number"}


def status_entity(agv: str) -> str:
    return f"urn:ngsi-ld:AGV:{agv}"


def movement_entity(agv: str) -> str:
    return f"urn:ngsi-ld:AGVMovement:{agv}"


def plant_text(mqtt_port: int, cb_port: int) -> str:
    """Both vehicles' channels, as in test_fleet_paper.py's plant (one vehicle there)."""
    out = [
        "@prefix pk: <https://w3id.org/plantkg/ontology#> .",
        "@prefix p: <https://w3id.org/plantkg/tests/fleet-fig7#> .",
        "@prefix owl: <http://www.w3.org/2002/07/owl#> .",
        "<https://w3id.org/plantkg/tests/fleet-fig7> a owl:Ontology ; owl:imports <https://w3id.org/plantkg/ontology> .",
        'p:agv-type a owl:NamedIndividual , pk:ResourceType ; pk:id "agv-interface-type" ; pk:name "AGV interface" .',
        'p:planner-type a owl:NamedIndividual , pk:ResourceType ; pk:id "task-planner-type" ; pk:name "Task planner" .',
    ]
    all_topics: list[str] = []
    outgoing: list[str] = []
    incoming: list[str] = []
    for n, agv in enumerate(AGVS, 1):
        topics = {
            "status": ("publishes", status_entity(agv), "AGV", 1, "true"),
            "movement": ("publishes", movement_entity(agv), "AGVMovement", 0, "false"),
            "description": ("publishes", f"urn:ngsi-ld:AGVDescription:{agv}", "AGVDescription", 1, "true"),
            "motion": ("subscribes", None, None, 1, "false"),
            "action": ("subscribes", None, None, 1, "false"),
        }
        names = {t: f"p:a{n}-{t}" for t in topics}
        all_topics += names.values()
        pubs = [names[t] for t, v in topics.items() if v[0] == "publishes"]
        subs = [names[t] for t, v in topics.items() if v[0] == "subscribes"]
        outgoing += pubs
        incoming += subs
        out.append(f'p:agv-{n} a owl:NamedIndividual , pk:Resource ; pk:id "agv-interface-{n}" ; pk:name "AGV {n}" ;')
        out.append(f"    pk:isType p:agv-type ; pk:sendsTo p:fleet-mqtt ; pk:publishes {' , '.join(pubs)} ;")
        out.append(f"    pk:subscribes {' , '.join(subs)} .")
        for name, (_, entity_id, entity_type, qos, retain) in topics.items():
            out.append(f'{names[name]} a owl:NamedIndividual , pk:Topic ; pk:id "a{n}-{name}-channel" ; '
                       f'pk:name "{agv}/{name}_channel" ;')
            out.append(f'    pk:valueTopic "{name}" ; pk:typeTopic "json" ; pk:qos {qos} ; pk:retain {retain}'
                       + (f' ; pk:entityId "{entity_id}" ; pk:entityType "{entity_type}"' if entity_id else "") + " .")
    out += [
        'p:task-planner a owl:NamedIndividual , pk:Resource ; pk:id "task-planner" ; pk:name "Task planner" ;',
        f"    pk:isType p:planner-type ; pk:sendsTo p:fleet-context ; pk:subscribes {' , '.join(outgoing)} ;",
        f"    pk:publishes {' , '.join(incoming)} .",
        f'p:fleet-mqtt a owl:NamedIndividual , pk:Broker ; pk:id "fleet-mqtt" ; pk:name "fleet-mqtt" ; '
        f'pk:brokerType "mosquitto" ; pk:ip "{MQTT_IP}" ; pk:port {mqtt_port} ; pk:allowAnonymous true ; '  # the sims log in as nobody
        f'pk:hasTopic {" , ".join(all_topics)} .',
        f'p:fleet-context a owl:NamedIndividual , pk:Broker ; pk:id "fleet-context" ; pk:name "fleet-context" ; '
        f'pk:brokerType "ngsi-v2" ; pk:ip "{CB_IP}" ; pk:port {cb_port} ; pk:hasTopic {" , ".join(all_topics)} .',
    ]
    return "\n".join(out) + "\n"


def header() -> dict[str, Any]:
    return {"seq": 0, "stamp": "2026-11-24T20:00:00.000Z", "frame_id": "hall-1"}


def entity(entity_id: str, item: dict[str, Any]) -> ContextEntity:
    attrs = {k: {"type": NGSI_TYPE.get(type(v), "StructuredValue"), "value": v} for k, v in item.items()}
    return ContextEntity(id=entity_id, type="Thing", **attrs)


class Poller(threading.Thread):
    """The independent NGSI client (the paper's JMeter): plain HTTP GETs of the status entities,
    every ``period`` s, each sample kept with its time."""

    def __init__(self, port: int, token: str, period: float = 0.05) -> None:
        """``token``: the context broker's agent's (closed by default: reads need it too)."""
        super().__init__(daemon=True, name="fig7-poller")
        self.base, self.period = f"http://{CB_IP}:{port}", period
        self.auth = {"Authorization": f"Bearer {token}"}
        self.samples: dict[str, list[tuple[float, dict[str, Any]]]] = {a: [] for a in AGVS}
        self.requests = 0
        self.failures = 0
        self._halt = threading.Event()

    def read(self, entity_id: str) -> dict[str, Any] | None:
        self.requests += 1
        try:
            with urllib.request.urlopen(urllib.request.Request(f"{self.base}/v2/entities/{entity_id}?options=keyValues",
                                                               headers=self.auth), timeout=5) as reply:
                return json.loads(reply.read())
        except urllib.error.HTTPError as exc:
            if exc.code != 404:  # 404: the vehicle has not published its status yet
                self.failures += 1
            return None
        except (OSError, ValueError):
            self.failures += 1
            return None

    def run(self) -> None:
        while not self._halt.is_set():
            for agv in AGVS:
                found = self.read(status_entity(agv))
                if found is not None:
                    self.samples[agv].append((time.monotonic(), found))
            self._halt.wait(self.period)

    def latest(self, agv: str) -> dict[str, Any]:
        return self.samples[agv][-1][1] if self.samples[agv] else {}

    def stop(self) -> None:
        self._halt.set()
        self.join(10)


@pytest.fixture
def plant(tmp_path: Path) -> Iterator[tuple[AgentFleet, Path]]:
    with agents_with_plant(tmp_path, plant_text, MQTT_IP, CB_IP) as made:
        yield made


def test_fig7_two_agvs_reach_their_points_in_order_and_an_ngsi_poller_sees_them_finish(
        plant, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from engine.cli import main

    fleet, path = plant
    agents = ["--agents", str(fleet.agents_file)]
    assert main(["apply", str(path), *agents, "--yes"]) == 0, capsys.readouterr()
    [mqtt_port] = [b.spec.port for b in fleet.client(MQTT_IP).list_brokers()]
    [cb_port] = [b.spec.port for b in fleet.client(CB_IP).list_brokers()]
    process.wait_until(lambda: [b for b in fleet.client(MQTT_IP).list_bridges()
                                if b.spec.mechanism is BridgeMechanism.NGSI and b.status.value == "running"],
                       DEADLINE, 0.2, what="the mqtt-ngsi bridge running")
    sim = process.spawn([sys.executable, "-m", "fleet.sim", "--interface", "paper", "--count", "2",
                         "--broker", f"{MQTT_IP}:{mqtt_port}", "--serial-prefix", "fig7-", "--rate", "2",
                         "--vmax", "1.5", "--amax", "1"], log_dir=tmp_path, name="fleet-sim-fig7", cwd=ROOT)
    session = requests.Session()
    session.headers["Authorization"] = f"Bearer {fleet.agents[CB_IP].token}"
    writer = filip_cb.ContextBrokerClient(url=f"http://{CB_IP}:{cb_port}", session=session,
                                          fiware_header=FiwareHeader())
    poller = Poller(cb_port, fleet.agents[CB_IP].token)
    poller.start()
    try:
        for agv in AGVS:
            process.wait_until(lambda a=agv: poller.latest(a).get("state") == "IDLE", DEADLINE, 0.05,
                               what=f"{agv} IDLE on the context broker", child=sim)
        plans: dict[str, dict[str, Any]] = {}
        began: dict[str, float] = {}
        for agv in AGVS:  # the REST calls: each point a motion item, in order, on the vehicle's motion entity
            task = str(uuid.uuid4())
            motions = [{"header": header(), "point_id": str(uuid.uuid4()), "task_id": task,
                        "motion_id": str(uuid.uuid4()), "point": point, "max_velocity": [1.5, 0.0, 1.0],
                        "max_acceleration": [1.0, 0.0, 1.0], "motion_area": AREA, "sequence": i + 1}
                       for i, point in enumerate(POINTS[agv])]
            plans[agv] = {"task": task, "motions": motions}
            began[agv] = time.monotonic()
            for item in motions:
                writer.post_entity(entity(f"urn:ngsi-ld:Thing:{agv}:motion_channel", item), update=True)
        for agv in AGVS:  # the wait action once the vehicle runs its first motion (two entities: two lanes)
            first = plans[agv]["motions"][0]["motion_id"]
            process.wait_until(lambda a=agv, m=first: any(s.get("motion_id") == m for _, s in poller.samples[a]),
                               DEADLINE, 0.05, what=f"{agv} running its first motion", child=sim)
            wait = {"header": header(), "action_id": str(uuid.uuid4()), "task_id": plans[agv]["task"],
                    "action": "wait", "sequence": len(POINTS[agv]) + 1, "duration": 0.5}
            writer.post_entity(entity(f"urn:ngsi-ld:Thing:{agv}:action_channel", wait), update=True)
        done: dict[str, float] = {}
        for agv in AGVS:
            process.wait_until(lambda a=agv: poller.latest(a).get("finished_task_id") == plans[a]["task"],
                               DEADLINE, 0.05, what=f"{agv} finished its task (seen by the poller)", child=sim)
            done[agv] = next(t for t, s in poller.samples[agv] if s.get("finished_task_id") == plans[agv]["task"])
        for agv in AGVS:
            final = poller.latest(agv)
            assert (final["state"], final["refused"], final["last_finished_sequence"]) == (
                "IDLE", 0, len(POINTS[agv]) + 1), final
            order = [m["motion_id"] for m in plans[agv]["motions"]]
            seen = [s.get("motion_id") for _, s in poller.samples[agv] if s.get("motion_id") in order]
            ranks = [order.index(m) for m in seen]
            assert ranks == sorted(ranks), (agv, ranks)  # never a point before an earlier one
            assert set(ranks) >= {0, len(order) - 1}, (agv, ranks)  # first and last seen running
            sequences = [s["last_finished_sequence"] for _, s in poller.samples[agv] if "last_finished_sequence" in s]
            assert sequences == sorted(sequences), (agv, sequences)
            goal = POINTS[agv][-1]
            response = session.get(f"http://{CB_IP}:{cb_port}/v2/entities/{movement_entity(agv)}?options=keyValues",
                                   timeout=5)
            pose = response.json()["pose"]
            assert math.hypot(pose["x"] - goal[0], pose["y"] - goal[1]) < 0.05, (agv, pose)
        assert "Traceback" not in sim.log_path.read_text(encoding="utf-8")
        assert poller.failures == 0  # every GET answered (200, or 404 before the vehicle was there)
        with capsys.disabled():
            for agv in AGVS:
                path_m = sum(math.dist(a, b) for a, b in zip([[PARK[AGVS.index(agv)].x, PARK[AGVS.index(agv)].y]]
                                                             + POINTS[agv], POINTS[agv]))
                print(f"\nFig. 7: {agv}: {len(POINTS[agv])} points ({path_m:.1f} m) + 0.5 s wait, finished "
                      f"{done[agv] - began[agv]:.1f} s after the first REST call (poller: {poller.requests} GETs, "
                      f"{poller.failures} failed)")
    finally:
        poller.stop()
        session.close()
        process.stop(sim)
    assert main(["destroy", str(path), *agents, "--yes"]) == 0
