"""The task planner fires LoTLan Events from MQTT and from the context broker, real processes:
agents, Mosquitto, the context broker, the fleet manager, two simulated VDA 5050 AGVs joined by plug
and play, and the planner (``python -m fleet.planner --events-mqtt ... --events-ngsi``). The rig is
tests/integration/test_fleet_planner.py's (its fixture and helpers, not its tests).

Two transports wait at their pickups on ``FinishedBy loaded == True`` / ``checked == True``:
- bad MQTT messages (not JSON, an unknown event, a string for a Boolean) are counted in the
  planner's ``GET /v1/tasks`` and logged; the planner goes on and the waiting step stays waiting;
- ``true`` published (by an independent paho client, QoS 1) on ``plantkg/events/Loaded`` finishes
  the first transport, journaled as any event;
- the planner restarted (SIGTERM, a new process): it reuses its subscription on the context broker
  (one with its description, the same id);
- an ``Event`` entity of an unknown event written on the context broker is refused and counted;
  ``Checked`` written (plain HTTP, ``POST /v2/op/update``) finishes the second transport;
- Mosquitto killed (kill -9) and restarted by its agent: the planner reconnects, subscribes again,
  and the next message fires.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time
import urllib.request
from pathlib import Path
from typing import Any

import pytest
from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import process
from engine.model import BrokerStatus
from tests.integration.test_fleet_planner import (  # noqa: F401 - rig is the module's fixture
    CB_HOST, MQTT_HOST, PARK, ROOT, Planner, Rig, cb_read, rig, spawn_sim, wait_ready, write_map,
)

pytestmark = pytest.mark.integration

JOBS = """\
Location loadStation
    name = "load-1"
    type = "pallet"
End

Location unloadStation
    name = "unload-1"
    type = "pallet"
End

Location otherLoad
    name = "load-2"
    type = "pallet"
End

Location otherUnload
    name = "unload-2"
    type = "pallet"
End

Event loaded
    name = "Loaded"
    type = "Boolean"
End

Event checked
    name = "Checked"
    type = "Boolean"
End

TransportOrderStep atLoad
    Location loadStation
    FinishedBy loaded == True
End

TransportOrderStep atUnload
    Location unloadStation
End

TransportOrderStep atOtherLoad
    Location otherLoad
    FinishedBy checked == True
End

TransportOrderStep atOtherUnload
    Location otherUnload
End

Task first
    Transport
    From atLoad
    To atUnload
End

Task second
    Transport
    From atOtherLoad
    To atOtherUnload
End
"""


class EventPlanner(Planner):
    """The rig's planner with the event sources on."""

    def start(self) -> process.Child:
        self.runs += 1
        self.child = process.spawn(
            [sys.executable, "-m", "fleet.planner", "--plant", self.rig.plant, "--lotlan", self.lotlan,
             "--data-dir", self.data, "--manager-data-dir", self.rig.data, "--map", self.map_file,
             "--ngsi-url", f"http://{CB_HOST}:{self.rig.cb_port}", "--ngsi-token-file", self.rig.cb_token_file,
             "--events-mqtt", f"{MQTT_HOST}:{self.rig.mqtt_port}", "--events-ngsi"],
            log_dir=self.rig.tmp / "logs", name=f"{self.name}-{self.runs}", cwd=ROOT)
        self.wait(lambda: self._where().get("pid") == self.child.pid, 30.0, "the planner's API")
        self.wait(lambda: (s := self.sources())["mqtt"]["subscribed"] and s["ngsi"]["subscription"], 30.0,
                  "subscribed on MQTT and the context broker")
        return self.child

    def sources(self) -> dict[str, Any]:
        return self.call("GET", "/v1/tasks")[1]["eventSources"]


def publish(rig: Rig, topic: str, payload: bytes) -> None:
    """One QoS 1 message from a client of its own (as an operator's button would send it)."""
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"test-events-{os.getpid()}")
    client.connect(MQTT_HOST, rig.mqtt_port, keepalive=10)
    client.loop_start()
    try:
        info = client.publish(topic, payload, qos=1)
        info.wait_for_publish(timeout=10)
        assert info.is_published(), f"{topic}: not acknowledged by Mosquitto"
    finally:
        client.disconnect()
        client.loop_stop()


def write_event(rig: Rig, name: str, value: Any) -> None:
    token = rig.cb_token_file.read_text(encoding="utf-8").splitlines()[0].strip()
    body = {"actionType": "append", "entities": [{"id": name, "type": "Event",
                                                  "value": {"type": "Boolean", "value": value}}]}
    request = urllib.request.Request(f"http://{CB_HOST}:{rig.cb_port}/v2/op/update", method="POST",
                                     data=json.dumps(body).encode(), headers={
                                         "Content-Type": "application/json", "Authorization": f"Bearer {token}"})
    with urllib.request.urlopen(request, timeout=10) as reply:
        assert reply.status == 204


def subscriptions(rig: Rig) -> list[dict[str, Any]]:
    with urllib.request.urlopen(cb_read(rig, "/v2/subscriptions?limit=1000"), timeout=10) as reply:
        return [s for s in json.loads(reply.read()) if (s.get("description") or "").startswith("plantkg task planner")]


def create_subscription(rig: Rig, body: dict[str, Any]) -> None:
    token = rig.cb_token_file.read_text(encoding="utf-8").splitlines()[0].strip()
    request = urllib.request.Request(f"http://{CB_HOST}:{rig.cb_port}/v2/subscriptions", method="POST",
                                     data=json.dumps(body).encode(), headers={
                                         "Content-Type": "application/json", "Authorization": f"Bearer {token}"})
    with urllib.request.urlopen(request, timeout=10) as reply:
        assert reply.status == 201


def fired(planner: Planner) -> list[tuple[str, Any]]:
    return [(r["event"], r["value"]) for r in planner.journal() if r["kind"] == "event"]


def test_events_from_mqtt_and_the_context_broker_finish_waiting_steps(
        rig: Rig, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:  # noqa: F811
    took: dict[str, float] = {}
    map_file = write_map(tmp_path / "map.json", PARK)
    lotlan = tmp_path / "jobs.tl"
    lotlan.write_text(JOBS, encoding="utf-8")
    sim = spawn_sim(rig, "ev-", map_file, 2, "sim-events")
    planner = EventPlanner(rig, tmp_path / "planner", lotlan, map_file, "planner-events")
    try:
        wait_ready(rig, ["ev-0001", "ev-0002"], sim)
        planner.start()
        assert planner.call("POST", "/v1/jobs", {}) == (201, {"job": "j1", "tasks": ["j1-first-1", "j1-second-1"]})
        planner.wait(lambda: all(t["legs"][0]["state"] == "ACTED" for t in planner.tasks().values()), 90.0,
                     "both picks done, waiting for Loaded / Checked")
        # bad messages: counted, logged, nothing fired, the planner goes on
        publish(rig, "plantkg/events/Loaded", b"yes")
        publish(rig, "plantkg/events/Ghost", b"true")
        publish(rig, "plantkg/events/Loaded", b'"pressed"')
        mqtt_status = planner.wait(lambda: (s := planner.sources()["mqtt"])["refused"] == 3 and s, 20.0,
                                   "3 bad MQTT messages counted")
        assert (mqtt_status["received"], mqtt_status["fired"]) == (3, 0), mqtt_status
        reasons = [r["reason"] for r in mqtt_status["lastRefusals"]]
        assert "payload: not JSON" in reasons[0] and "'Ghost' is no Event" in reasons[1] \
            and "value: Event loaded is of type Boolean" in reasons[2], reasons
        assert planner.child is not None and planner.child.running()
        assert "plantkg/events/Ghost: refused" in planner.logs()
        assert planner.tasks()["j1-first-1"]["legs"][0]["state"] == "ACTED" and fired(planner) == []
        # the operator's button
        start = time.monotonic()
        publish(rig, "plantkg/events/Loaded", b"true")
        process.wait_until(lambda: fired(planner), 20.0, 0.005, what="Loaded journaled", child=planner.child)
        took["MQTT publish -> journaled"] = time.monotonic() - start
        planner.wait(lambda: planner.tasks()["j1-first-1"]["state"] == "FINISHED", 60.0, "first FINISHED")
        assert fired(planner) == [("loaded", True)]
        assert planner.tasks()["j1-second-1"]["legs"][0]["state"] == "ACTED"  # Loaded does not finish Checked
        subs = subscriptions(rig)
        assert len(subs) == 1 and subs[0]["subject"]["entities"] == [{"idPattern": ".*", "type": "Event"}], subs
        # restarted: the same subscription, no second one (a duplicate, as a crash between create and
        # list could leave, is deleted)
        copy = {k: subs[0][k] for k in ("description", "subject")}
        copy["notification"] = {k: subs[0]["notification"][k] for k in ("httpCustom", "attrs", "attrsFormat")}
        create_subscription(rig, copy)
        assert len(subscriptions(rig)) == 2
        planner.stop()
        planner.start()
        after = subscriptions(rig)
        assert [s["id"] for s in after] == [subs[0]["id"]], after
        assert planner.sources()["ngsi"]["subscription"] == subs[0]["id"]
        assert after[0]["notification"]["httpCustom"]["url"].endswith("/v1/ngsi/notify")
        # an Event entity nobody declared: refused and counted; then Checked finishes the second
        write_event(rig, "Ghost", True)
        ngsi = planner.wait(lambda: (s := planner.sources()["ngsi"])["refused"] == 1 and s, 20.0,
                            "the unknown Event entity refused")
        assert "'Ghost' is no Event" in ngsi["lastRefusals"][0]["reason"] and ngsi["fired"] == 0
        start = time.monotonic()
        write_event(rig, "Checked", True)
        process.wait_until(lambda: len(fired(planner)) == 2, 20.0, 0.005, what="Checked journaled",
                           child=planner.child)
        took["NGSI write -> journaled"] = time.monotonic() - start
        planner.wait(lambda: planner.tasks()["j1-second-1"]["state"] == "FINISHED", 60.0, "second FINISHED")
        assert fired(planner) == [("loaded", True), ("checked", True)]
        assert planner.sources()["ngsi"]["fired"] == 1
        # Mosquitto killed -9, restarted by its agent: paho reconnects, the planner subscribes again
        agent = rig.agents.client(MQTT_HOST)
        broker = next(b for b in agent.list_brokers() if b.spec.port == rig.mqtt_port)
        assert broker.pid is not None and planner.sources()["mqtt"]["connects"] == 1
        os.kill(broker.pid, signal.SIGKILL)
        process.wait_until(lambda: (b := agent.get_broker(broker.spec.id)) is not None and b.pid != broker.pid
                           and b.status is BrokerStatus.RUNNING, 60.0, 0.1, what="Mosquitto restarted by its agent")
        planner.wait(lambda: (s := planner.sources()["mqtt"])["connects"] == 2 and s["subscribed"], 30.0,
                     "the planner subscribed again")
        publish(rig, "plantkg/events/Loaded", b'{"value": true}')
        planner.wait(lambda: planner.sources()["mqtt"]["fired"] == 1, 20.0, "the event after the restart fired")
        assert fired(planner) == [("loaded", True), ("checked", True), ("loaded", True)]
        with capsys.disabled():  # a figure, not asserted (2 shared cores)
            print("\nplanner events: " + ", ".join(f"{k} {v * 1000:.0f} ms" for k, v in took.items()))
    finally:
        planner.stop()
        assert process.stop(sim, grace=15.0) == 0, sim.log_tail()
