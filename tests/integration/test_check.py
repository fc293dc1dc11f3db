"""``plantkg check`` against real agents and brokers: the paper's robot cell.

Two ``plantkg agent`` processes serve 127.0.0.2 (Mosquitto) and 127.0.0.3 (Kafka); the plant is a
copy of ontology/examples/robot-cell.ttl with free ports, applied once for the module. In file
order: ``--probe`` passes (the exact probe reaches Mosquitto and, through the bridge worker, Kafka);
passive passes while simulated resources publish (engine.demo.simulate) and reports "no traffic" when
none do; an unreachable broker or agent exits 2; then the Mosquitto -> Kafka bridge is deleted on
its agent (nothing re-creates it: no reconcile loop runs) and both modes exit 1 naming the ROS
machine, the robot's position topic, Kafka and the bridge. The fixture stops the sources, deletes
what is left and checks that no broker process survived.
"""

from __future__ import annotations

import json
import os
import threading
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import netutil, process
from engine.cli import main
from engine.demo.run import feeds
from engine.model import BridgeStatus
from engine.demo.simulate import Source
from tests.integration.agents import AgentFleet, _alive, plant_copy, set_port, start_agents

pytestmark = pytest.mark.integration

MQTT_HOST, KAFKA_HOST = "127.0.0.2", "127.0.0.3"
POSITION, ENERGY = "robot.abb-irb120.position", "robot.abb-irb120.energy"
PASS_DEADLINE = "30"   # generous: a passing check ends as soon as everything arrived
FAIL_DEADLINE = "8"    # a failing check waits it out; a short one cannot make a failure pass


@dataclass
class Cell:
    fleet: AgentFleet
    plant: Path
    ports: dict[str, int]
    tmp: Path

    def check(self, capsys: pytest.CaptureFixture[str], *args: str | Path,
              plant: Path | None = None) -> tuple[int, str, str]:
        code = main(["check", str(plant or self.plant), "--agents", str(self.fleet.agents_file),
                     *(str(a) for a in args)])
        out = capsys.readouterr()
        return code, out.out, out.err


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cell]:
    tmp = tmp_path_factory.mktemp("check-cell")
    fleet = start_agents([MQTT_HOST, KAFKA_HOST], tmp)
    try:
        plant, ports = plant_copy("robot-cell.ttl", tmp)
        assert main(["apply", str(plant), "--agents", str(fleet.agents_file), "--yes"]) == 0
        agent = fleet.client(MQTT_HOST)
        # the worker subscribes at Mosquitto after apply returns: a probe published before would
        # be lost to it, so wait for "running" (connected to both ends, subscriptions granted)
        process.wait_until(lambda: [b for b in agent.list_bridges() if b.status is BridgeStatus.RUNNING],
                           60.0, 0.2, what="the Mosquitto -> Kafka bridge running")
        fleet.brokers()  # remember the broker pids for the final check
        fleet.broker_pids |= {b.pid for b in agent.list_bridges() if b.pid}  # and the worker's
        yield Cell(fleet, plant, ports, tmp)
        assert main(["destroy", str(plant), "--agents", str(fleet.agents_file), "--yes"]) == 0
    finally:
        fleet.stop()


@pytest.fixture
def sources(cell: Cell) -> Iterator[list[Source]]:
    """The plant's publishing resources, simulated (the ROS machine at 10 Hz, the Pi at 1 Hz)."""
    stop = threading.Event()
    running = [Source(feed, stop) for feed in feeds([str(cell.plant)])]
    assert sorted(s.feed.resource for s in running) == ["ROS machine", "Raspberry Pi"]
    for source in running:
        source.start()
    try:
        process.wait_until(lambda: all(s.sent for s in running), 30.0, 0.05, what="every source publishing")
        yield running
    finally:
        stop.set()
        for source in running:
            source.join(20)
        assert not any(s.is_alive() for s in running)


def _flows(out: str) -> dict[str, dict]:
    doc = json.loads(out)
    return {f["topic"]: f for f in doc["flows"]}


# -------------------------------------------------------------------------------- the tests

def test_probe_passes_on_the_applied_cell(cell: Cell, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = cell.check(capsys, "--probe", "--deadline", PASS_DEADLINE, "--format", "json")
    assert code == 0, out + err
    doc = json.loads(out)
    assert doc["passed"] is True and doc["mode"] == "probe" and doc["deadline_s"] == 30.0
    assert doc["counts"] == {"pass": 2, "fail": 0, "no-traffic": 0, "not-checked": 0}
    flows = _flows(out)
    position = flows[POSITION]
    assert position["resource"] == "ROS machine" and position["source"] == "mosquitto"
    # exactly one probe at each broker: published at Mosquitto, carried by the worker to Kafka
    assert [(b["broker"], b["arrived"], b["hops"]) for b in position["brokers"]] == [
        ("mosquitto", 1, 0), ("kafka", 1, 1)]
    assert position["brokers"][1]["via"] == [
        {"bridge": "bridge.mosquitto.kafka", "from": "mosquitto", "mechanism": "mqtt-kafka"}]
    assert position["brokers"][1]["port"] == cell.ports["kafka"]
    assert [(b["broker"], b["arrived"]) for b in flows[ENERGY]["brokers"]] == [("kafka", 1)]
    assert not position["warnings"] and isinstance(doc["elapsed_s"], float)


def test_passive_passes_while_the_resources_publish(cell: Cell, sources: list[Source],
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    code, out, err = cell.check(capsys, "--deadline", PASS_DEADLINE)
    assert code == 0, out + err
    lines = out.splitlines()
    assert any(line.startswith("ok") and "ROS machine (ros-machine) on robot.abb-irb120.position" in line
               and "arrived at mosquitto, kafka" in line for line in lines), out
    assert any(line.startswith("ok") and "Raspberry Pi" in line for line in lines), out
    assert "2 flow(s), passive, deadline 30 s: 2 passed, 0 failed, 0 not checked" in out


def _publish_retained(port: int, payload: bytes) -> None:
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"it-check-{uuid.uuid4().hex[:8]}")
    # the robot cell's Mosquitto is closed: as the ROS machine (its throwaway password: conftest)
    client.username_pw_set("ros-machine", os.environ["PLANTKG_ROS_MACHINE_PASSWORD"])
    client.connect(MQTT_HOST, port)
    client.loop_start()
    try:
        process.wait_until(client.is_connected, 10.0, 0.01, what="MQTT CONNACK")
        info = client.publish(POSITION, payload, qos=1, retain=True)
        info.wait_for_publish(10)
        assert info.is_published()
    finally:
        client.disconnect()
        client.loop_stop()


def test_passive_without_publishers_reports_no_traffic(cell: Cell, capsys: pytest.CaptureFixture[str]) -> None:
    """Nobody publishes: each flow fails at its source. Neither the probes of earlier runs nor a
    retained message (old news, sent to new subscribers) count as traffic."""
    _publish_retained(cell.ports["mosquitto"], b'{"joints_deg": [0, 0, 0, 0, 0, 0]}')
    try:
        code, out, err = cell.check(capsys, "--deadline", "3", "--format", "json")
    finally:
        _publish_retained(cell.ports["mosquitto"], b"")  # an empty retained message clears it
    assert code == 1, out + err
    flows = _flows(out)
    assert flows[POSITION]["outcome"] == flows[ENERGY]["outcome"] == "no-traffic"
    assert flows[POSITION]["message"] == (
        "no traffic from ROS machine (ros-machine) on robot.abb-irb120.position at mosquitto within 3 s")
    assert "no traffic from Raspberry Pi (raspberry-pi) on robot.abb-irb120.energy at kafka" in flows[ENERGY]["message"]


def test_an_unreachable_broker_exits_2(cell: Cell, capsys: pytest.CaptureFixture[str]) -> None:
    other = cell.tmp / "wrong-port.ttl"
    other.write_text(cell.plant.read_text(encoding="utf-8"), encoding="utf-8")
    set_port(other, "mosquitto", netutil.free_port(MQTT_HOST))  # nothing listens there
    code, out, err = cell.check(capsys, "--deadline", "5", plant=other)
    assert code == 2, out + err
    assert "error: mosquitto (mosquitto at 127.0.0.2:" in err and "cannot connect" in err
    assert "Traceback" not in out + err


def test_an_unreachable_agent_exits_2(cell: Cell, capsys: pytest.CaptureFixture[str]) -> None:
    agents = cell.tmp / "wrong-agents.toml"
    port = netutil.free_port(MQTT_HOST)
    text = cell.fleet.agents_file.read_text(encoding="utf-8")
    url = cell.fleet.agents[MQTT_HOST].url
    assert url in text
    agents.write_text(text.replace(url, f"http://{MQTT_HOST}:{port}"), encoding="utf-8")
    code = main(["check", str(cell.plant), "--agents", str(agents), "--deadline", "5"])
    out = capsys.readouterr()
    assert code == 2, out
    assert "agents that did not answer: 127.0.0.2" in out.err and "Traceback" not in out.err


def test_a_deleted_bridge_fails_the_flow_naming_resource_broker_and_bridge(
        cell: Cell, sources: list[Source], capsys: pytest.CaptureFixture[str]) -> None:
    agent = cell.fleet.client(MQTT_HOST)
    (bridge,) = agent.list_bridges()
    agent.delete_bridge("mosquitto", "kafka")
    process.wait_until(lambda: not agent.list_bridges(), 30.0, 0.1, what="the bridge gone from its agent")
    if bridge.pid:
        process.wait_until(lambda: not _alive(bridge.pid), 30.0, 0.1, what="the bridge worker exited")

    code, out, err = cell.check(capsys, "--probe", "--deadline", FAIL_DEADLINE)
    assert code == 1, out + err
    assert ("FAIL ROS machine (ros-machine) on robot.abb-irb120.position: the probe reached mosquitto but "
            "nothing arrived at kafka within 8 s: bridge bridge.mosquitto.kafka from mosquitto "
            "(mqtt-kafka, absent: no agent runs it)") in out
    assert any(line.startswith("ok") and "Raspberry Pi" in line for line in out.splitlines()), out
    assert "1 passed, 1 failed" in out

    code, out, err = cell.check(capsys, "--deadline", FAIL_DEADLINE, "--format", "json")
    assert code == 1, out + err
    flows = _flows(out)
    assert flows[ENERGY]["outcome"] == "pass"
    position = flows[POSITION]
    assert position["outcome"] == "fail" and position["resource"] == "ROS machine"
    mosquitto, kafka = position["brokers"]
    assert mosquitto["broker"] == "mosquitto" and mosquitto["arrived"] > 0  # the source kept publishing
    assert kafka["broker"] == "kafka" and kafka["arrived"] == 0
    assert "nothing arrived at kafka" in position["message"] and "bridge.mosquitto.kafka" in position["message"]



# ------------------------------------------------------------- two bridge paths into one broker

DIAMOND = """\
@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <http://example.org/check-diamond#> .

:a a pk:Broker ; pk:id "a" ; pk:name "a" ; pk:brokerType "mosquitto" ; pk:ip "{host}" ; pk:port {a} ;
    pk:hasTopic :t ; pk:bridgesTo :b , :c .
:b a pk:Broker ; pk:id "b" ; pk:name "b" ; pk:brokerType "mosquitto" ; pk:ip "{host}" ; pk:port {b} ;
    pk:hasTopic :t ; pk:bridgesTo :c .
:c a pk:Broker ; pk:id "c" ; pk:name "c" ; pk:brokerType "mosquitto" ; pk:ip "{host}" ; pk:port {c} ;
    pk:hasTopic :t .
:t a pk:Topic ; pk:id "t" ; pk:name "line.t" ; pk:qos 1 .
:sensor a pk:Resource ; pk:id "sensor" ; pk:name "Line sensor" ; pk:sendsTo :a ; pk:publishes :t .
"""


def test_a_probe_delivered_twice_through_two_bridge_paths_is_reported(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A -> B -> C and A -> C (Mosquitto bridges; no cycle, so the plant is valid): C gets each
    message of A twice. The check passes (everything arrived) and warns, naming both bridges."""
    fleet = start_agents([MQTT_HOST], tmp_path)
    try:
        ports: list[int] = []
        while len(ports) < 3:
            port = netutil.free_port(MQTT_HOST)
            if port not in ports:
                ports.append(port)
        plant = tmp_path / "diamond.ttl"
        plant.write_text(DIAMOND.format(host=MQTT_HOST, a=ports[0], b=ports[1], c=ports[2]), encoding="utf-8")
        args = ["check", str(plant), "--agents", str(fleet.agents_file), "--probe", "--deadline", PASS_DEADLINE]
        assert main(["apply", str(plant), "--agents", str(fleet.agents_file), "--yes"]) == 0
        fleet.brokers()
        # Mosquitto's bridges connect after apply returns: wait until a probe gets everywhere
        process.wait_until(lambda: main([*args, "--format", "json"]) == 0, 120.0, 0.5,
                           what="the diamond's bridges carrying a probe")
        capsys.readouterr()
        code = main([*args, "--format", "json"])
        out = capsys.readouterr().out
        assert code == 0, out
        (flow,) = json.loads(out)["flows"]
        assert flow["outcome"] == "pass"
        assert {b["broker"]: b["arrived"] for b in flow["brokers"]} == {"a": 1, "b": 1, "c": 2}
        (warning,) = flow["warnings"]
        assert warning.startswith("the probe arrived 2 times at c: two bridge paths deliver the same messages twice")
        assert "bridge.a.c from a" in warning and "bridge.b.c from b" in warning
        assert main(["destroy", str(plant), "--agents", str(fleet.agents_file), "--yes"]) == 0
    finally:
        fleet.stop()


# ------------------------------------------------------------------- a context broker: not checked

def test_flows_through_a_context_broker_are_listed_as_not_checked(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The AGV middleware: the AGV publishes on Mosquitto, bridged into the context broker; the task
    planner writes entities that come back on MQTT. check watches the Mosquitto side, lists the
    context broker as not checked and skips the flows published there — never a pass for them."""
    plant, _ = plant_copy("agv-middleware.ttl", tmp_path)
    fleet = start_agents([MQTT_HOST, KAFKA_HOST], tmp_path / "agents")
    agents = ["--agents", str(fleet.agents_file)]
    try:
        assert main(["apply", str(plant), *agents, "--yes"]) == 0
        fleet.brokers()
        capsys.readouterr()
        code = main(["check", str(plant), *agents, "--probe", "--deadline", PASS_DEADLINE, "--format", "json"])
        out = capsys.readouterr().out
        assert code == 0, out
        doc = json.loads(out)
        assert doc["counts"] == {"pass": 3, "fail": 0, "no-traffic": 0, "not-checked": 2}
        for flow in doc["flows"]:
            brokers = {b["broker"]: b for b in flow["brokers"]}
            assert brokers["fleet-context"]["checked"] is False and brokers["fleet-context"]["arrived"] is None
            assert "not checked: fleet-context is a ngsi-v2 broker" in brokers["fleet-context"]["note"]
            if flow["source"] == "fleet-mqtt":
                assert flow["outcome"] == "pass" and brokers["fleet-mqtt"]["arrived"] == 1
            else:
                assert flow["source"] == "fleet-context" and flow["outcome"] == "not-checked"
                assert flow["resource"] == "Task planner" and flow["probe_id"] is None
        assert main(["destroy", str(plant), *agents, "--yes"]) == 0
    finally:
        fleet.stop()
