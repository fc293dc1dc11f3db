"""VDA 5050 2.1 between our simulator and an outside implementation (PyPI vda5050-sdk), on a real Mosquitto.

(a) ``python -m fleet.sim`` is the vehicle, the sdk's ``MasterClient`` (its pydantic models and the
    official JSON schemas checking everything it receives) is the master: the vehicle announces
    itself (retained ONLINE), answers a factsheetRequest, drives the order and reports the last
    node and FINISHED actions; kill -9 makes the broker publish the last will CONNECTIONBROKEN, a
    clean SIGTERM publishes OFFLINE for every vehicle.
(b) the sdk's ``VehicleClient`` + ``OrderExecutor`` is the vehicle and our message layer the
    master: our order JSON is accepted and executed, and its state messages pass our schema checks.
"""

from __future__ import annotations

import asyncio
import json
import os
import queue
import signal
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest
from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import netutil, parts, process
from engine.drivers.mosquitto import runtime as mosquitto_runtime
from fleet.vda5050 import schemas, topics
from fleet.vda5050.errors import SchemaError
from fleet.vda5050.headers import HeaderCounter
from fleet.vda5050.messages import Action, ActionParameter, BlockingType, Edge, Node, NodePosition, Order, State

pytestmark = pytest.mark.integration

HOST = "127.0.0.1"
ROOT = Path(__file__).resolve().parents[2]
FAST = ["--vmax", "2", "--amax", "2", "--omega-max", "4", "--alpha-max", "8"]


@pytest.fixture
def mosquitto(tmp_path: Path) -> Iterator[int]:
    port = netutil.free_port(HOST)
    cfg = mosquitto_runtime.MosquittoConfig(host=HOST, port=port, log_file=tmp_path / "mosquitto.log",
                                            run_as=mosquitto_runtime.default_run_as())
    conf = tmp_path / "mosquitto.conf"
    conf.write_text(mosquitto_runtime.render_mosquitto_conf(cfg), encoding="utf-8")
    broker = process.spawn(mosquitto_runtime.mosquitto_command(parts.mosquitto_binary(), conf),
                           log_dir=tmp_path, name="mosquitto-stdout")
    try:
        process.wait_until(lambda: netutil.port_open(HOST, port), 10.0, 0.01, what="Mosquitto", child=broker)
        yield port
    finally:
        process.stop(broker, grace=5.0)
    assert not broker.group_alive()


def start_sim(port: int, tmp_path: Path, *args: str) -> process.Child:
    return process.spawn([sys.executable, "-m", "fleet.sim", "--broker", f"{HOST}:{port}", *args],
                         log_dir=tmp_path, name="fleet-sim", cwd=ROOT)


class Watcher:
    """A plain paho subscriber that keeps (topic, payload, retain, qos) of everything it gets."""

    def __init__(self, port: int, topic_filter: str) -> None:
        self.messages: queue.Queue[tuple[str, dict, bool, int]] = queue.Queue()
        self.client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"watch-{os.getpid()}-{id(self)}")
        self.client.on_message = lambda _c, _u, m: self.messages.put((m.topic, json.loads(m.payload), m.retain, m.qos))
        self.client.on_connect = lambda c, *_: c.subscribe(topic_filter, qos=1)
        self.client.connect(HOST, port)
        self.client.loop_start()

    def wait_for(self, predicate, timeout: float = 15.0) -> tuple[str, dict, bool, int]:
        def poll():
            try:
                item = self.messages.get(timeout=0.05)
            except queue.Empty:
                return None
            return item if predicate(item) else None
        return process.wait_until(poll, timeout, 0.0, what="an MQTT message")

    def close(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def sdk_order(path: list[tuple[str, float, float]], order_id: str):
    from vda5050.model.order import Order as SdkOrder

    nodes = tuple(Node(name, 2 * i, True, (Action("pick", f"{order_id}-pick", BlockingType.HARD, (ActionParameter("duration", 0.5),)),) if i == len(path) - 1 else (),
                       NodePosition(x, y, "hall-1")) for i, (name, x, y) in enumerate(path))
    edges = tuple(Edge(f"{a[0]}-{b[0]}", 2 * i + 1, a[0], b[0]) for i, (a, b) in enumerate(zip(path, path[1:])))
    dummy = {"headerId": 0, "timestamp": "2026-01-01T00:00:00.000Z", "version": "2.1.0", "manufacturer": "x", "serialNumber": "x"}
    return SdkOrder.model_validate(Order(order_id, 0, nodes, edges).to_json(dummy))


def test_sdk_master_drives_our_simulated_vehicle(mosquitto: int, tmp_path: Path) -> None:
    from vda5050 import MasterClient, MasterConfig

    sim = start_sim(mosquitto, tmp_path, "--count", "1", "--serial-prefix", "it-", "--rate", "5", *FAST)
    watcher = Watcher(mosquitto, "uagv/v2/plantkg/it-0001/connection")
    target = "plantkg/it-0001"
    try:
        async def scenario() -> dict:
            master = MasterClient(MasterConfig(broker_url=f"mqtt://{HOST}:{mosquitto}", validate_messages=True, visualization=True))
            errors, factsheets, connections, states, visuals = [], [], [], [], []
            master.on_error(errors.append)
            master.on_factsheet(lambda f, _k: factsheets.append(f))
            master.on_connection(lambda c, _k: connections.append(c.connection_state.value))
            master.on_state(lambda s, _k: states.append(s))
            master.on_visualization(lambda v, _k: visuals.append(v))
            await master.connect()
            try:
                async def until(check, timeout=20.0):
                    for _ in range(int(timeout / 0.05)):
                        if check():
                            return True
                        await asyncio.sleep(0.05)
                    return False
                assert await until(lambda: "ONLINE" in connections), f"no ONLINE; errors {errors}"
                assert await until(lambda: states), "no state"
                await master.request_factsheet(target)
                assert await until(lambda: factsheets), f"no factsheet; errors {errors}"
                # park-1 of the default map is (20, 4): a square of 2 m sides, pick at the end
                order = sdk_order([("park-1", 20, 4), ("a", 22, 4), ("b", 22, 6), ("c", 20, 6)], "o-1")
                result = await master.dispatch(order, target)
                assert result.accepted, result
                done = await master.wait_for_action(target, "o-1-pick", timeout=60)
                session = await master.session(target)
                return {"done": done, "errors": errors, "state": session.state, "factsheet": factsheets[0],
                        "visuals": len(visuals), "drove": any(s.driving for s in states)}
            finally:
                await master.disconnect()

        got = asyncio.run(scenario())
        state = got["state"]
        assert got["done"], f"pick never finished; last state {state}"
        assert got["errors"] == [], [str(e) for e in got["errors"]]  # the sdk validated everything we sent
        assert (state.last_node_id, state.last_node_sequence_id) == ("c", 6)
        assert {a.action_id: a.action_status.value for a in state.action_states}["o-1-pick"] == "FINISHED"
        assert state.node_states == [] and state.edge_states == [] and got["drove"]
        assert (round(state.agv_position.x, 3), round(state.agv_position.y, 3)) == (20.0, 6.0)
        assert got["factsheet"].physical_parameters.speed_max == 2.0
        assert got["visuals"] > 0

        # connection: ONLINE, retained, QoS 1 (a late subscriber gets it)
        late = Watcher(mosquitto, "uagv/v2/plantkg/it-0001/connection")
        try:
            _, message, retained, qos = late.wait_for(lambda m: True)
            assert (message["connectionState"], retained, qos) == ("ONLINE", True, 1)
        finally:
            late.close()

        os.killpg(sim.pid, signal.SIGKILL)
        sim.popen.wait(timeout=10)
        _, will, _, qos = watcher.wait_for(lambda m: m[1]["connectionState"] != "ONLINE")
        assert (will["connectionState"], qos) == ("CONNECTIONBROKEN", 1)
        schemas.check("connection", will)
    finally:
        watcher.close()
        process.stop(sim, grace=5.0)


def test_clean_stop_says_offline_for_every_vehicle(mosquitto: int, tmp_path: Path) -> None:
    sim = start_sim(mosquitto, tmp_path, "--count", "3", "--serial-prefix", "stop-")
    watcher = Watcher(mosquitto, "uagv/v2/plantkg/+/connection")
    try:
        online = set()
        while len(online) < 3:
            topic, message, _, _ = watcher.wait_for(lambda m: m[1]["connectionState"] == "ONLINE")
            online.add(topics.parse(topic).serial)
        assert process.stop(sim, grace=10.0) == 0
        offline = set()
        while len(offline) < 3:
            topic, message, _, _ = watcher.wait_for(lambda m: m[1]["connectionState"] != "ONLINE")
            assert message["connectionState"] == "OFFLINE"
            offline.add(topics.parse(topic).serial)
        assert offline == online == {"stop-0001", "stop-0002", "stop-0003"}
        assert "OFFLINE confirmed for 3 of 3" in sim.log_path.read_text()
    finally:
        watcher.close()
        process.stop(sim, grace=5.0)


def test_our_order_drives_the_sdk_vehicle_and_its_states_pass_our_checks(mosquitto: int) -> None:
    from vda5050 import VehicleClient, VehicleConfig

    serial = "sdk-1"
    states: list[dict] = []
    refused: list[SchemaError] = []
    watcher = Watcher(mosquitto, f"uagv/v2/other/{serial}/state")

    async def scenario() -> None:
        vehicle = VehicleClient(VehicleConfig(broker_url=f"mqtt://{HOST}:{mosquitto}", manufacturer="other",
                                              serial_number=serial, state_interval=1.0, validate_messages=True))
        runs: list[asyncio.Task] = []
        await vehicle.connect()
        vehicle.update_position(x=0.0, y=0.0, theta=0.0, map_id="hall-1")
        vehicle.on_order(lambda order: runs.append(asyncio.ensure_future(vehicle.executor.run(order))))
        master = mqtt.Client(CallbackAPIVersion.VERSION2, client_id="plantkg-master-test")
        master.connect(HOST, mosquitto)
        master.loop_start()
        try:
            headers = HeaderCounter("other", serial)
            nodes = (Node("n0", 0, True, (), NodePosition(0.0, 0.0, "hall-1")),
                     Node("n1", 2, True, (Action("pick", "p1", BlockingType.HARD),), NodePosition(1.0, 0.0, "hall-1")),
                     Node("n2", 4, True, (Action("drop", "d1", BlockingType.HARD),), NodePosition(2.0, 0.0, "hall-1")))
            edges = (Edge("e0", 1, "n0", "n1"), Edge("e1", 3, "n1", "n2"))
            wire = Order("our-order", 0, nodes, edges).to_json(headers.next("order"))
            schemas.check("order", wire)
            rule = topics.rule("order")
            master.publish(topics.topic("other", serial, "order"), json.dumps(wire), qos=rule.qos, retain=rule.retain).wait_for_publish(5)
            for _ in range(400):
                if runs and runs[0].done():
                    break
                await asyncio.sleep(0.05)
            assert runs and runs[0].done(), "the sdk vehicle never finished our order"
            await vehicle.publish_state()
            for _ in range(200):  # poll (deadline 10 s) until the final state reached the watcher
                drain()
                if states and states[-1].get("lastNodeId") == "n2" and all(
                        a["actionStatus"] == "FINISHED" for a in states[-1]["actionStates"]):
                    break
                await asyncio.sleep(0.05)
        finally:
            master.disconnect()
            master.loop_stop()
            await vehicle.disconnect()

    def drain() -> None:
        while not watcher.messages.empty():
            _, message, _, _ = watcher.messages.get()
            try:
                states.append(schemas.check("state", message))
            except SchemaError as exc:
                refused.append(exc)

    try:
        asyncio.run(scenario())
        drain()
    finally:
        watcher.close()
    assert not refused, [str(e) for e in refused]
    assert states, "no state from the sdk vehicle"
    last = State.from_json(states[-1])
    assert (last.order_id, last.last_node_id, last.last_node_sequence_id) == ("our-order", "n2", 4)
    assert last.action_status("p1").value == "FINISHED" and last.action_status("d1").value == "FINISHED"
    assert last.errors == ()


def test_a_bad_order_is_refused_with_its_schema_path_and_changes_nothing(mosquitto: int, tmp_path: Path) -> None:
    sim = start_sim(mosquitto, tmp_path, "--count", "1", "--serial-prefix", "bad-", "--state-interval", "1")
    watcher = Watcher(mosquitto, "uagv/v2/plantkg/bad-0001/state")
    try:
        watcher.wait_for(lambda m: True)  # the vehicle is up
        headers = HeaderCounter("plantkg", "bad-0001")
        order = Order("evil", 0, (Node("n0", 0, True, (), NodePosition(20.0, 4.0, "hall-1")),)).to_json(headers.next("order"))
        order["nodes"][0]["sequenceId"] = "zero"
        watcher.client.publish(topics.topic("plantkg", "bad-0001", "order"), json.dumps(order)).wait_for_publish(5)
        _, state, _, _ = watcher.wait_for(lambda m: m[1]["errors"])
        error = state["errors"][-1]
        assert error["errorType"] == "validationError" and error["errorLevel"] == "WARNING"
        assert error["errorDescription"].startswith("order: nodes/0/sequenceId: 'zero' is not of type 'integer'")
        assert state["orderId"] == "" and state["nodeStates"] == []  # nothing else changed
        schemas.check("state", state)
        process.wait_until(lambda: "refused order" in sim.log_path.read_text(), 5.0, 0.05, what="the log line")
    finally:
        watcher.close()
        process.stop(sim, grace=5.0)


def test_vehicles_come_back_online_after_a_broker_restart(tmp_path: Path) -> None:
    port = netutil.free_port(HOST)
    cfg = mosquitto_runtime.MosquittoConfig(host=HOST, port=port, log_file=tmp_path / "mosquitto.log",
                                            run_as=mosquitto_runtime.default_run_as())
    conf = tmp_path / "mosquitto.conf"
    conf.write_text(mosquitto_runtime.render_mosquitto_conf(cfg), encoding="utf-8")
    argv = mosquitto_runtime.mosquitto_command(parts.mosquitto_binary(), conf)

    def start_broker(name: str) -> process.Child:
        child = process.spawn(argv, log_dir=tmp_path, name=name)
        process.wait_until(lambda: netutil.port_open(HOST, port), 10.0, 0.01, what="Mosquitto", child=child)
        return child

    broker = start_broker("mosquitto-1")
    sim = start_sim(port, tmp_path, "--count", "2", "--serial-prefix", "re-")
    try:
        first = Watcher(port, "uagv/v2/plantkg/+/connection")
        try:
            first.wait_for(lambda m: m[0].endswith("re-0002/connection") and m[1]["connectionState"] == "ONLINE")
        finally:
            first.close()
        process.stop(broker, grace=5.0)  # no persistence: the restarted broker knows nothing
        broker = start_broker("mosquitto-2")
        again = Watcher(port, "uagv/v2/plantkg/+/connection")
        try:
            back = set()
            while len(back) < 2:  # reconnect back-off is at most 5 s
                topic, message, _, _ = again.wait_for(lambda m: m[1]["connectionState"] == "ONLINE", timeout=15)
                back.add(topics.parse(topic).serial)
            assert back == {"re-0001", "re-0002"}
        finally:
            again.close()
    finally:
        process.stop(sim, grace=10.0)
        process.stop(broker, grace=5.0)
