"""Live message rates on real brokers: two ``plantkg agent`` processes run two real Mosquitto
brokers (the web tests' plant: mqtt-a bridges the robot's position topic to mqtt-b), ``plantkg
serve``'s server runs in this process (engine.web.server.start_server, the rate monitor with it),
and a real paho client publishes. Every wait polls with a deadline; no timing is asserted.

- messages published on a topic are counted at its broker and, through the bridge, at the next;
  a topic without traffic stays at 0;
- a restarted broker (a new pid) gets a new tap and its messages are counted again;
- a broker that accepts TCP but never answers MQTT does not stop the others, and stopping the
  monitor leaves no thread behind;
- the dashboard in a real Chromium draws a sparkline for the topic with traffic.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import threading
import urllib.request
import uuid
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest

from engine import netutil, process
from engine.agent.server import ListenAddress
from engine.cli import main
from engine.model import BrokerSpec, BrokerStatus, ObservedBroker, TopicSpec
from engine.web.plant_state import PlantState
from engine.web.rates import RateMonitor
from engine.web.server import RunningServer, start_server
from engine.web.sparql_protocol import Limits
from tests.integration.agents import AgentFleet, start_agents
from tests.web.plants import MACHINES, write_mosquitto_plant

pytestmark = pytest.mark.integration

POSITION, TEMPERATURE = "cell.robot-1.position", "cell.sensor-1.temperature"
DEADLINE = 60.0
CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"


@dataclass
class Plant:
    url: str
    fleet: AgentFleet
    running: RunningServer
    ports: dict[str, int]

    def rates(self) -> dict:
        with urllib.request.urlopen(self.url + "/api/rates", timeout=10) as answer:
            return json.loads(answer.read())

    def topic(self, broker: str, topic: str) -> dict | None:
        found = [t for t in self.rates()["topics"] if (t["broker"], t["topic"]) == (broker, topic)]
        return found[0] if found else None

    def broker(self, broker_id: str) -> ObservedBroker | None:
        observed = self.running.state.snapshot.observed
        return observed.broker(broker_id) if observed else None


@pytest.fixture(scope="module")
def plant(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Plant]:
    tmp = tmp_path_factory.mktemp("web-rates")
    ports = {"mqtt-a": netutil.free_port(MACHINES[0]), "mqtt-b": netutil.free_port(MACHINES[1])}
    path = write_mosquitto_plant(tmp / "plant.ttl", ports["mqtt-a"], ports["mqtt-b"])
    fleet = start_agents(list(MACHINES), tmp)
    running, threads = None, set(threading.enumerate())
    try:
        assert main(["apply", str(path), "--agents", str(fleet.agents_file), "--yes"]) == 0
        state = PlantState([str(path)], fleet.agents_file, observe_interval=1.0)
        running = start_server(ListenAddress("127.0.0.1", 0), state, "rates-test-token-0123456789", Limits())
        yield Plant(running.address.url, fleet, running, ports)
    finally:
        if running is not None:
            running.shutdown()
        fleet.brokers()  # remember their pids: fleet.stop checks none survives
        assert main(["destroy", str(path), "--agents", str(fleet.agents_file), "--yes"]) == 0
        fleet.stop()
        assert not rate_threads(threads), f"threads left by the server's rate monitor: {rate_threads(threads)}"


def rate_threads(before: set[threading.Thread]) -> list[str]:
    """Threads of a rate monitor and its taps (paho's loop of a tap's client, a Kafka tap's poller)
    started since ``before``."""
    return [t.name for t in set(threading.enumerate()) - before if t.is_alive() and t.name.startswith(
        ("plantkg-rates-", "plantkg-web-rates", "paho-mqtt-client-plantkg-check-", "check-tap-"))]


def publish(host: str, port: int, topic: str, count: int, login: tuple[str, str] | None = None) -> None:
    """``count`` QoS 1 messages, each acknowledged by the broker."""
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"rates-test-{uuid.uuid4().hex[:8]}")
    if login is not None:
        client.username_pw_set(*login)
    client.connect(host, port)
    client.loop_start()
    try:
        for i in range(count):
            client.publish(topic, json.dumps({"i": i}), qos=1).wait_for_publish(30)
    finally:
        client.disconnect()
        client.loop_stop()


def watching(plant: Plant, broker: str, topic: str) -> dict:
    return process.wait_until(lambda: (t := plant.topic(broker, topic)) and t["watching"] and t,
                              DEADLINE, 0.2, what=f"a tap watching {topic} at {broker}")


def total_reaches(plant: Plant, broker: str, topic: str, total: int) -> dict:
    return process.wait_until(lambda: (t := plant.topic(broker, topic)) and t["total"] >= total and t,
                              DEADLINE, 0.2, what=f"{total} messages of {topic} counted at {broker}")


def test_published_messages_are_counted_per_broker_and_second(plant: Plant) -> None:
    before = watching(plant, "mqtt-a", POSITION)["total"]
    before_b = watching(plant, "mqtt-b", POSITION)["total"]
    quiet = watching(plant, "mqtt-b", TEMPERATURE)
    publish(MACHINES[0], plant.ports["mqtt-a"], POSITION, 40)
    at_a = total_reaches(plant, "mqtt-a", POSITION, before + 40)
    total_reaches(plant, "mqtt-b", POSITION, before_b + 40)  # carried by the Mosquitto bridge
    assert at_a["total"] == before + 40
    # per_s ends with the last complete second: it may still lack the messages of this second
    seen = process.wait_until(lambda: sum(plant.topic("mqtt-a", POSITION)["per_s"]) >= 40 or None,
                              DEADLINE, 0.2, what="the 40 messages in the last minute's buckets")
    assert seen
    doc = plant.rates()
    assert doc["window_s"] == 60 and doc["enabled"] is True
    for row in doc["topics"]:
        assert len(row["per_s"]) == 60 and all(type(n) is int and n >= 0 for n in row["per_s"])
        assert type(row["total"]) is int and row["error"] is None
    assert {(t["broker"], t["topic"]) for t in doc["topics"]} == {
        ("mqtt-a", POSITION), ("mqtt-b", POSITION), ("mqtt-b", TEMPERATURE)}
    assert plant.topic("mqtt-b", TEMPERATURE)["total"] == quiet["total"] == 0


def test_a_restarted_broker_is_watched_again(plant: Plant) -> None:
    old = plant.broker("mqtt-a")
    assert old is not None and old.pid
    plant.fleet.client(MACHINES[0]).broker_verb("mqtt-a", "restart")
    process.wait_until(lambda: (b := plant.broker("mqtt-a")) and b.status is BrokerStatus.RUNNING and b.pid != old.pid,
                       DEADLINE, 0.2, what="the dashboard seeing mqtt-a's new pid")
    before = watching(plant, "mqtt-a", POSITION)["total"]
    # the new tap may subscribe a moment after the topic row says watching: publish until counted
    process.wait_until(lambda: publish(MACHINES[0], plant.ports["mqtt-a"], POSITION, 5)
                       or plant.topic("mqtt-a", POSITION)["total"] > before, DEADLINE, 0.5,
                       what="messages after the restart counted", ignore=(OSError,))


def test_a_tap_kicked_off_its_broker_is_renewed(plant: Plant) -> None:
    """Another client with the tap's client id takes its session over (MQTT's rule); paho then
    reconnects the tap by itself, without its subscriptions: the monitor must make a new tap."""
    monitor = RateMonitor(lambda: (plant.running.state.snapshot.desired, plant.running.state.snapshot.observed),
                          interval=0.2).start()
    try:
        def runner():  # type: ignore[no-untyped-def]
            return next(r for t, r in monitor._runners.items() if t.endpoint.broker == "mqtt-a")

        process.wait_until(lambda: runner().watching, DEADLINE, 0.1, what="mqtt-a watched")
        first = runner().tap
        intruder = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, protocol=mqtt.MQTTv5,
                               client_id=first._client._client_id.decode())
        intruder.connect(MACHINES[0], plant.ports["mqtt-a"])
        intruder.loop_start()
        process.wait_until(intruder.is_connected, DEADLINE, 0.05, what="the intruder connected")
        intruder.disconnect()
        intruder.loop_stop()
        process.wait_until(lambda: runner().tap is not first and runner().watching, DEADLINE, 0.1,
                           what="a new tap after the reconnect")
        before = monitor.book.rows()
        total = next(n for b, t, _, n in before if (b, t) == ("mqtt-a", POSITION))
        publish(MACHINES[0], plant.ports["mqtt-a"], POSITION, 7)
        process.wait_until(lambda: [n for b, t, _, n in monitor.book.rows() if (b, t) == ("mqtt-a", POSITION)]
                           == [total + 7], DEADLINE, 0.1, what="messages after the renewal counted")
    finally:
        monitor.stop()


def _silent_broker() -> socket.socket:
    """A TCP port that accepts connections (the kernel's backlog) but never answers MQTT."""
    listener = socket.socket()
    listener.bind((MACHINES[0], 0))
    listener.listen(8)
    return listener


def test_a_silent_broker_does_not_stop_the_others_and_stop_leaves_no_thread(plant: Plant) -> None:
    silent = _silent_broker()
    ghost = BrokerSpec("ghost", "urn:ghost", "ghost", "mosquitto", MACHINES[0], silent.getsockname()[1])

    def source():  # type: ignore[no-untyped-def]
        snap = plant.running.state.snapshot
        desired = replace(snap.desired, brokers=(*snap.desired.brokers, ghost),
                          topics=(TopicSpec("ghost", "g", "urn:g"), *snap.desired.topics))
        observed = replace(snap.observed, brokers=(ObservedBroker(ghost, BrokerStatus.RUNNING, pid=1),
                                                   *snap.observed.brokers))
        return desired, observed

    threads_before = set(threading.enumerate())
    monitor = RateMonitor(source, interval=0.2, connect_timeout=2.0).start()
    try:
        def row(broker: str, topic: str) -> dict | None:
            found = [t for t in monitor.document()["topics"] if (t["broker"], t["topic"]) == (broker, topic)]
            return found[0] if found else None

        process.wait_until(lambda: (r := row("mqtt-a", POSITION)) and r["watching"], DEADLINE, 0.1,
                           what="mqtt-a watched beside a silent broker")
        process.wait_until(lambda: (r := row("ghost", "g")) and r["error"], DEADLINE, 0.1,
                           what="the silent broker's error")
        assert "no CONNACK" in row("ghost", "g")["error"] and not row("ghost", "g")["watching"]
        publish(MACHINES[0], plant.ports["mqtt-a"], POSITION, 10)
        process.wait_until(lambda: row("mqtt-a", POSITION)["total"] >= 10, DEADLINE, 0.1,
                           what="mqtt-a's messages counted while the silent broker is retried")
    finally:
        monitor.stop()
        silent.close()
    left = rate_threads(threads_before)
    assert not left, f"threads left by the rate monitor: {left}"
    assert monitor.threads() == []


def test_the_dashboard_draws_a_sparkline_for_a_topic_with_traffic(plant: Plant, tmp_path: Path) -> None:
    if not Path(CHROMIUM).exists():
        pytest.fail(f"no Chromium at {CHROMIUM}: run `make setup` (it installs Debian's chromium)")
    from playwright.sync_api import sync_playwright

    stop = threading.Event()

    def traffic() -> None:
        while not stop.is_set():
            publish(MACHINES[0], plant.ports["mqtt-a"], POSITION, 10)
            stop.wait(0.2)

    cell = '#topics td.rate[data-broker="mqtt-a"][data-topic="cell.robot-1.position"]'
    quiet = '#topics td.rate[data-broker="mqtt-b"][data-topic="cell.sensor-1.temperature"]'
    publisher = threading.Thread(target=traffic, daemon=True)
    publisher.start()
    try:
        with sync_playwright() as pw:
            browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True)
            try:
                page = browser.new_page()
                errors: list[str] = []
                page.on("pageerror", lambda exc: errors.append(str(exc)))
                page.goto(plant.url + "/")
                # a drawn line that leaves the baseline (17.0) of an 18 px high sparkline: traffic
                process.wait_until(lambda: page.evaluate(
                    f"""(() => {{ const line = document.querySelector('{cell} svg.sparkline polyline');
                    return !!line && line.getAttribute('points').split(' ')
                        .some(p => parseFloat(p.split(',')[1]) < 17); }})()"""), DEADLINE, 0.2,
                    what="a sparkline showing mqtt-a's traffic")
                assert int(page.get_attribute(cell, "data-rate") or "-1") >= 0
                assert page.inner_text(cell).endswith("/s")
                assert page.evaluate(f"""document.querySelector('{quiet} svg.sparkline polyline')
                    .getAttribute('points').split(' ').every(p => p.endsWith(',17.0'))""")
                page.locator("#topics").screenshot(path=str(tmp_path / "rates.png"))
                assert (tmp_path / "rates.png").stat().st_size > 1000
                assert not errors, f"JavaScript errors: {errors}"
            finally:
                browser.close()
    finally:
        stop.set()
        publisher.join(30)


KAFKA_POSITION, KAFKA_ENERGY = "robot.abb-irb120.position", "robot.abb-irb120.energy"


@pytest.fixture
def cell(tmp_path: Path) -> Iterator[Plant]:
    """The paper's robot cell: Mosquitto on 127.0.0.2, Kafka on 127.0.0.3, the bridge worker."""
    from engine.model import BridgeStatus
    from tests.integration.agents import plant_copy

    fleet = start_agents(list(MACHINES), tmp_path)
    running, threads = None, set(threading.enumerate())
    try:
        path, ports = plant_copy("robot-cell.ttl", tmp_path)
        assert main(["apply", str(path), "--agents", str(fleet.agents_file), "--yes"]) == 0
        agent = fleet.client(MACHINES[0])
        process.wait_until(lambda: [b for b in agent.list_bridges() if b.status is BridgeStatus.RUNNING],
                           DEADLINE, 0.2, what="the Mosquitto -> Kafka bridge running")
        fleet.broker_pids |= {b.pid for b in agent.list_bridges() if b.pid}  # the worker's too
        state = PlantState([str(path)], fleet.agents_file, observe_interval=1.0)
        running = start_server(ListenAddress("127.0.0.1", 0), state, "rates-test-token-0123456789", Limits())
        yield Plant(running.address.url, fleet, running, ports)
    finally:
        if running is not None:
            running.shutdown()
        fleet.brokers()
        assert main(["destroy", str(tmp_path / "plant.ttl"), "--agents", str(fleet.agents_file), "--yes"]) == 0
        fleet.stop()
        assert not rate_threads(threads), f"threads left by the server's rate monitor: {rate_threads(threads)}"


def test_kafka_topics_are_counted_from_their_end(cell: Plant) -> None:
    from confluent_kafka import Producer

    for broker, topic in (("mosquitto", KAFKA_POSITION), ("kafka", KAFKA_POSITION), ("kafka", KAFKA_ENERGY)):
        watching(cell, broker, topic)
    before = {(b, t): cell.topic(b, t)["total"] for b, t in (("mosquitto", KAFKA_POSITION),
                                                              ("kafka", KAFKA_POSITION), ("kafka", KAFKA_ENERGY))}
    # the robot cell's Kafka is closed (closed by default): as the Raspberry Pi, which may write the
    # energy topic (its throwaway password: conftest); the dashboard's tap logs in as plantkg
    producer = Producer({"bootstrap.servers": f"{MACHINES[1]}:{cell.ports['kafka']}", "acks": "all",
                         "log_level": 0, "security.protocol": "SASL_PLAINTEXT", "sasl.mechanism": "SCRAM-SHA-512",
                         "sasl.username": "raspberry-pi", "sasl.password": os.environ["PLANTKG_RASPBERRY_PI_PASSWORD"]})
    delivered: list[object] = []
    for i in range(25):
        producer.produce(KAFKA_ENERGY, json.dumps({"i": i}).encode(), on_delivery=lambda err, _m: delivered.append(err))
    assert producer.flush(30) == 0 and delivered == [None] * 25
    # the robot cell's Mosquitto is closed: as the ROS machine (its throwaway password: conftest)
    publish(MACHINES[0], cell.ports["mosquitto"], KAFKA_POSITION, 30,
            login=("ros-machine", os.environ["PLANTKG_ROS_MACHINE_PASSWORD"]))
    assert total_reaches(cell, "kafka", KAFKA_ENERGY, before[("kafka", KAFKA_ENERGY)] + 25)["total"] \
        == before[("kafka", KAFKA_ENERGY)] + 25
    assert total_reaches(cell, "mosquitto", KAFKA_POSITION, before[("mosquitto", KAFKA_POSITION)] + 30)["total"] \
        == before[("mosquitto", KAFKA_POSITION)] + 30
    total_reaches(cell, "kafka", KAFKA_POSITION, before[("kafka", KAFKA_POSITION)] + 30)  # through the worker
