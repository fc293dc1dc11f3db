"""fleet.manager.service without a network: messages are put into the link's inbox by the test,
what the manager sends is recorded; the reconcile step is the real validation (no agents). Checks
the batching (joins within the window make one run), that OFFLINE needs no run, that refusals
and states reach status.json, and that a person's change of the data directory makes a run."""

from __future__ import annotations

import json
import queue
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from engine import process
from fleet.discovery.records import DataDir
from fleet.manager import apply_step
from fleet.manager.mqtt_link import Received
from fleet.manager.plant import binding_and_address
from fleet.manager.service import FleetManager, ManagerConfig, render_record
from tests.unit.fleet import discovery_data as d

PLANT = Path(__file__).resolve().parents[3] / "ontology" / "examples" / "agv-fleet.ttl"


class RecordingLink:
    """The MqttLink's surface: an inbox the test fills, and what the manager sends."""

    def __init__(self) -> None:
        self.inbox: queue.Queue[Received] = queue.Queue()
        self.connected = threading.Event()
        self.dropped = 0
        self.sent: list[tuple[str, str, str]] = []  # (manufacturer, serial, action type)
        self._n = 0

    def start(self) -> None:
        self.connected.set()

    def stop(self) -> None:
        self.connected.clear()

    def instant_action(self, manufacturer: str, serial: str, action_type: str, parameters: tuple = ()) -> str:
        self.sent.append((manufacturer, serial, action_type))
        self.parameters = parameters
        return action_type

    def header(self, manufacturer: str, serial: str, subtopic: str) -> dict[str, object]:
        return {"headerId": 0, "timestamp": "2026-11-24T20:00:00.000Z", "version": "2.1.0",
                "manufacturer": manufacturer, "serialNumber": serial}

    def next_id(self, prefix: str) -> str:
        self._n += 1
        return f"{prefix}-{self._n}"

    def publish(self, topic: str, message: dict[str, Any], subtopic: str) -> None:
        self.sent.append(("", topic, subtopic))

    def put(self, topic: str, message: Any, retained: bool = False) -> None:
        payload = message if isinstance(message, bytes) else d.wire(message)
        self.inbox.put(Received(topic, payload, retained, time.monotonic()))


@pytest.fixture
def running(tmp_path: Path) -> Iterator[tuple[FleetManager, RecordingLink, list[list[Path]]]]:
    binding, address = binding_and_address([PLANT])
    config = ManagerConfig((PLANT,), tmp_path, address, binding, batch_window=0.3, poll_interval=0.1,
                           status_interval=0.05, resync=3600)
    runs: list[list[Path]] = []

    def step(files: list[Path]) -> apply_step.StepResult:
        runs.append(list(files))
        return apply_step.check(files)
    link = RecordingLink()
    manager = FleetManager(config, step, link=link)  # type: ignore[arg-type]
    thread = threading.Thread(target=manager.run)
    thread.start()
    try:
        process.wait_until(lambda: runs and manager.last_report, 20.0, what="the first run")
        yield manager, link, runs
    finally:
        manager.stop()
        thread.join(20)
    assert not thread.is_alive()


def status(manager: FleetManager) -> dict[str, Any]:
    try:
        return json.loads((manager.data.root / "status.json").read_text())
    except (OSError, ValueError):
        return {}


def test_joins_within_the_window_make_one_run_and_offline_needs_none(running: Any) -> None:
    manager, link, runs = running
    for i in (1, 2, 3):
        link.put(d.topic("connection", "acme", f"v-{i}"), d.connection("ONLINE", "acme", f"v-{i}"), retained=True)
    process.wait_until(lambda: len(link.sent) == 3, 10.0, what="three factsheet requests")
    assert link.sent == [("acme", f"v-{i}", "factsheetRequest") for i in (1, 2, 3)]
    for i in (1, 2, 3):
        link.put(d.topic("factsheet", "acme", f"v-{i}"), d.factsheet("acme", f"v-{i}"))
    rows = process.wait_until(lambda: (s := status(manager).get("vehicles", [])) and len(s) == 3
                              and all(v["readySeconds"] is not None for v in s) and s, 20.0, what="three ready")
    assert len(runs) == 2 and len(runs[1]) == 2  # the start, then one run for the batch of three
    assert runs[1][1].read_text(encoding="utf-8").count("# --- ") == 3  # (bundled in one file)
    assert {v["vehicle"] for v in rows} == {"acme/v-1", "acme/v-2", "acme/v-3"}
    assert sorted(s for s in link.sent if s[2] == "stateRequest") == [("acme", f"v-{i}", "stateRequest") for i in (1, 2, 3)]

    link.put(d.topic("state", "acme", "v-1"), d.state("acme", "v-1"))
    link.put(d.topic("connection", "acme", "v-2"), d.connection("CONNECTIONBROKEN", "acme", "v-2"))
    rows = process.wait_until(lambda: (s := {v["serial"]: v for v in status(manager).get("vehicles", [])})
                              and s["v-2"]["connectionState"] == "CONNECTIONBROKEN" and s["v-1"]["state"] and s,
                              10.0, what="v-2 unavailable and v-1's state")
    assert rows["v-1"]["state"]["lastNodeId"] == "n2" and rows["v-1"]["state"]["batteryCharge"] == 81.5
    assert rows["v-2"]["available"] is False
    assert 'fleet:connectionState "CONNECTIONBROKEN"' in (manager.data.discovered / "acme--v-2.ttl").read_text()
    # a vehicle joining after the OFFLINE is the next run: the OFFLINE made none of its own
    link.put(d.topic("factsheet", "acme", "v-4"), d.factsheet("acme", "v-4"))
    process.wait_until(lambda: manager.last_report and "acme--v-4" in manager.last_report["joined"], 20.0,
                       what="v-4 joined")
    assert len(runs) == 3


def test_refused_messages_and_vehicles_reach_the_status(running: Any) -> None:
    manager, link, runs = running
    link.put("uagv/v2/acme/bad#1/connection", b"{}")
    bad = d.factsheet("acme", "neg-1")
    bad["physicalParameters"]["speedMax"] = -1.0
    link.put(d.topic("factsheet", "acme", "neg-1"), bad)
    s = process.wait_until(lambda: (s := status(manager)) and s.get("refusedMessages") and s.get("refused") and s,
                           10.0, what="both refusals in the status")
    assert "character '#'" in s["refusedMessages"][0]["reason"]
    assert s["refused"][0]["vehicle"] == "acme--neg-1" and "speedMax" in s["refused"][0]["reason"]
    assert s["vehicles"] == [] and len(runs) == 1


def test_a_change_of_the_data_directory_by_a_person_makes_a_run(running: Any) -> None:
    manager, link, runs = running
    link.put(d.topic("factsheet", "acme", "p-1"), d.factsheet("acme", "p-1"))
    process.wait_until(lambda: len(runs) == 2 and manager.last_report and "acme--p-1" in manager.last_report["joined"],
                       20.0, what="p-1 joined")
    data = DataDir(manager.data.root, render_record)
    with data.lock():
        data.update(data.find("p-1"), name="Renamed")
    process.wait_until(lambda: len(runs) == 3, 10.0, what="a run after the rename")
    with data.lock():
        data.remove(data.find("p-1"))
    process.wait_until(lambda: len(runs) == 4 and status(manager).get("vehicles") == [], 10.0,
                       what="a run after the removal")
    assert all(p.name != "acme--p-1.ttl" for p in runs[-1])


def test_an_admitted_vehicle_makes_a_run_then_joins_when_heard_keeping_its_secret_ref(running: Any) -> None:
    """``plantkg fleet admit`` while the manager runs: a run for the admission (its user), the
    factsheet asked when it says ONLINE, its description joined with the ``pk:secretRef`` kept,
    and its readiness measured from that ONLINE."""
    from fleet.discovery.admission import admit

    manager, link, runs = running
    secret = manager.data.root.parent / "a-1.pw"
    admit(DataDir(manager.data.root, render_record), manager.config.binding, "vda5050", "acme", "a-1", secret)
    process.wait_until(lambda: len(runs) == 2, 10.0, what="a run after the admission")
    assert f'pk:secretRef "file:{secret}"' in runs[1][1].read_text(encoding="utf-8")
    link.put(d.topic("connection", "acme", "a-1"), d.connection("ONLINE", "acme", "a-1"), retained=True)
    process.wait_until(lambda: ("acme", "a-1", "factsheetRequest") in link.sent, 10.0, what="its factsheet asked")
    link.put(d.topic("factsheet", "acme", "a-1"), d.factsheet("acme", "a-1"))
    row = process.wait_until(lambda: (v := next(iter(status(manager).get("vehicles", [])), None))
                             and v["readySeconds"] is not None and v, 20.0, what="a-1 ready")
    assert "pick" in row["skills"] and row["connectionState"] == "ONLINE"
    text = (manager.data.discovered / "acme--a-1.ttl").read_text(encoding="utf-8")
    assert f'pk:secretRef "file:{secret}"' in text and "fleet:discovered true" in text
    [record] = manager.data.records()
    assert not record.awaiting_description and record.secret_ref == f"file:{secret}"


def test_a_paper_vehicle_admitted_under_another_manufacturer_keeps_one_file(running: Any) -> None:
    """The paper's topics carry no manufacturer: a vehicle admitted as ``other`` that describes
    itself as ``plantkg-sim`` is one vehicle, one file (the admitted one goes), its secret kept."""
    from fleet.discovery.admission import admit

    manager, link, runs = running
    secret = manager.data.root.parent / "agv-7.pw"
    admit(DataDir(manager.data.root, render_record), manager.config.binding, "paper-channels", "other", "agv-7",
          secret)
    process.wait_until(lambda: len(runs) == 2, 10.0, what="a run after the admission")
    link.put("agv-7/description_channel", d.paper_description(), retained=True)
    process.wait_until(lambda: manager.last_report and "plantkg-sim--agv-7" in manager.last_report["joined"], 20.0,
                       what="agv-7 joined")
    assert [p.name for p in manager.data.turtle_files()] == ["plantkg-sim--agv-7.ttl"]
    [record] = manager.data.records()
    assert record.secret_ref == f"file:{secret}" and record.manufacturer == "plantkg-sim"
