"""The operator's verbs against a real ``plantkg agent`` and real brokers (issue 15).

- ``restart`` gives a new pid and loses nothing (a retained MQTT message, persisted by Mosquitto);
- ``stop`` keeps the broker stopped (status stopped-by-operator): the supervisor, an agent restart
  (SIGTERM and kill -9) and a PUT do not start it, and a plan of the plant shows no change;
- ``start`` serves again; a Kafka topic's messages produced before ``stop`` are consumed after
  ``start``;
- the command line (``plantkg stop|start|restart``) finds the agent and exits 2 on an unknown
  broker;
- ``serve``'s reconcile loop leaves a stopped broker stopped; the dashboard's ``/api/stop|start|
  restart`` work behind its login and CSRF token.

The agents and their clean-up come from tests/integration/test_agent.py (imported, not copied).
"""

from __future__ import annotations

import queue
import subprocess
import uuid
from pathlib import Path

import pytest
from confluent_kafka import Consumer, KafkaException, Producer, TopicPartition
from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import netutil, process
from engine.agent.procs import proc_info
from engine.errors import PermanentDispatchError, WaitTimeoutError
from engine.model import Action, BrokerSpec, BrokerStatus, DesiredState, ObservedState, TopicSpec
from engine.plan import plan
from tests.integration.test_agent import (  # noqa: F401 - agents is a fixture
    HOST,
    PLANTKG,
    Agents,
    agents,
    mosquitto_processes,
    mqtt_roundtrip,
    mqtt_spec,
)

pytestmark = pytest.mark.integration


def publish_retained(port: int, topic: str, payload: bytes) -> None:
    pub = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"pub-{uuid.uuid4().hex[:8]}")
    pub.connect(HOST, port, keepalive=10)
    pub.loop_start()
    try:
        process.wait_until(pub.is_connected, 10.0, 0.005, what="CONNACK")
        pub.publish(topic, payload, qos=1, retain=True).wait_for_publish(timeout=10)
    finally:
        pub.disconnect()
        pub.loop_stop()


def read_retained(port: int, topic: str) -> bytes:
    """The retained message a new subscriber of ``topic`` gets (fails after 10 s without one)."""
    received: queue.Queue[bytes] = queue.Queue()
    sub = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"sub-{uuid.uuid4().hex[:8]}")
    sub.on_message = lambda _c, _u, msg: received.put(msg.payload)
    sub.connect(HOST, port, keepalive=10)
    sub.loop_start()
    try:
        process.wait_until(sub.is_connected, 10.0, 0.005, what="CONNACK")
        sub.subscribe(topic, qos=1)
        return received.get(timeout=10)
    finally:
        sub.disconnect()
        sub.loop_stop()


def cli(agents_file: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(PLANTKG), *args, "--agents", str(agents_file)], capture_output=True,
                          text=True, timeout=180, check=False)


def write_agents_file(tmp_path: Path, url: str, token_file: Path) -> Path:
    path = tmp_path / "agents.toml"
    path.write_text(f'[agents."{HOST}"]\nurl = "{url}"\ntoken_file = "{token_file}"\n',
                    encoding="utf-8")
    path.chmod(0o600)
    return path


def test_restart_gives_a_new_pid_and_keeps_a_retained_message(agents: Agents, tmp_path: Path) -> None:
    state = tmp_path / "state"
    agent = agents.start(state, "--stop-brokers-on-exit")
    client = agent.client()
    spec = mqtt_spec()
    first = client.put_broker(spec)
    publish_retained(spec.port, "cell/robot/pose", b"x=1")

    again = client.broker_verb("m1", "restart")
    assert again.status is BrokerStatus.RUNNING
    assert again.pid != first.pid and proc_info(first.pid) is None
    assert mosquitto_processes(state, "m1") == [again.pid]
    assert again.restarts == first.restarts  # an operator's restart is no crash
    assert read_retained(spec.port, "cell/robot/pose") == b"x=1"
    assert agent.terminate() == 0


def test_stop_keeps_it_stopped_until_started(agents: Agents, tmp_path: Path) -> None:
    state = tmp_path / "state"
    agent = agents.start(state)  # default: brokers outlive the agent
    client = agent.client()
    spec = mqtt_spec()
    first = client.put_broker(spec)
    publish_retained(spec.port, "cell/a", b"kept")
    folder = state / "brokers" / "m1"

    stopped = client.broker_verb("m1", "stop")
    assert stopped.status is BrokerStatus.STOPPED_BY_OPERATOR and stopped.pid is None
    assert proc_info(first.pid) is None and not netutil.port_open(HOST, spec.port)
    assert (folder / "spec.json").is_file() and (folder / "stopped.json").is_file()
    assert client.broker_verb("m1", "stop").status is BrokerStatus.STOPPED_BY_OPERATOR  # idempotent

    # The plan sees it present and meant to be down: no change at all.
    listed = client.list_brokers()
    result = plan(DesiredState(brokers=(spec,)), ObservedState(brokers=tuple(listed)))
    assert result.empty, result.changes
    assert [c.action for c in result.changes] == [Action.NOOP]
    assert "stopped by the operator" in (result.changes[0].reason or "")

    # A PUT would start it: refused (409) with what to do, and nothing starts.
    with pytest.raises(PermanentDispatchError) as info:
        client.put_broker(spec)
    assert "409" in info.value.message and "stopped by the operator" in info.value.message
    assert "plantkg start m1" in (info.value.hint or "")

    # kill -9 the agent, start another on the same state dir: still stopped, no process.
    agent.kill9()
    again = agents.start(state, port=agent.port)
    held = again.client().get_broker("m1")
    assert held is not None and held.status is BrokerStatus.STOPPED_BY_OPERATOR
    assert mosquitto_processes(state, "m1") == []
    with pytest.raises(WaitTimeoutError):  # the supervisor ticks every 0.1 s: it had 10 chances
        process.wait_until(lambda: mosquitto_processes(state, "m1"), 1.0, 0.05,
                           what="no broker to be started")

    started = again.client().broker_verb("m1", "start")
    assert started.status is BrokerStatus.RUNNING and started.pid
    assert not (folder / "stopped.json").exists()
    assert read_retained(spec.port, "cell/a") == b"kept"
    mqtt_roundtrip(spec.port)
    assert again.client().broker_verb("m1", "start").pid == started.pid  # running: left alone
    again.client().delete_broker("m1")
    assert again.terminate() == 0


def test_the_command_line_finds_the_agent(agents: Agents, tmp_path: Path) -> None:
    state = tmp_path / "state"
    agent = agents.start(state, "--stop-brokers-on-exit")
    spec = mqtt_spec()
    first = agent.client().put_broker(spec)
    agents_file = write_agents_file(tmp_path, agent.url, state / "token")

    done = cli(agents_file, "restart", "broker.m1")
    assert done.returncode == 0, done.stderr
    now = agent.client().get_broker("m1")
    assert now.pid != first.pid and f"pid {first.pid} → {now.pid}" in done.stdout

    done = cli(agents_file, "stop", "m1")
    assert done.returncode == 0, done.stderr
    assert "stopped-by-operator" in done.stdout
    assert agent.client().get_broker("m1").status is BrokerStatus.STOPPED_BY_OPERATOR

    done = cli(agents_file, "start", "m1")
    assert done.returncode == 0, done.stderr
    assert agent.client().get_broker("m1").status is BrokerStatus.RUNNING
    mqtt_roundtrip(spec.port)

    unknown = cli(agents_file, "stop", "nope")
    assert unknown.returncode == 2
    assert "no agent runs broker 'nope'" in unknown.stderr and "Traceback" not in unknown.stderr
    agent.client().delete_broker("m1")
    assert agent.terminate() == 0


def test_stop_keeps_a_kafka_topics_messages(agents: Agents, tmp_path: Path) -> None:
    state = tmp_path / "state"
    agent = agents.start(state, "--stop-brokers-on-exit")
    client = agent.client()
    spec = BrokerSpec(id="k1", iri="https://example.org/plant#k1", name="Cell Kafka", kind="kafka",
                      host=HOST, port=netutil.free_port(HOST))
    bootstrap = f"{HOST}:{spec.port}"
    client.put_broker(spec)
    topic = TopicSpec(broker_id="k1", name="robot.pose", iri="https://example.org/plant#pose",
                      partitions=2)
    client.put_topic(topic)
    producer = Producer({"bootstrap.servers": bootstrap, "acks": "all"})
    sent = [f"pose-{i}".encode() for i in range(20)]
    for value in sent:
        producer.produce("robot.pose", value=value, partition=1)
    assert producer.flush(30) == 0
    del producer

    stopped = client.broker_verb("k1", "stop")
    assert stopped.status is BrokerStatus.STOPPED_BY_OPERATOR
    assert not netutil.port_open(HOST, spec.port)
    assert [(t.name, t.partitions) for t in stopped.topics] == [("robot.pose", 2)]  # kept, shown
    result = plan(DesiredState(brokers=(spec,), topics=(topic,)),
                  ObservedState(brokers=tuple(client.list_brokers())))
    assert result.empty, [c for c in result.changes if c.action is not Action.NOOP]

    started = client.broker_verb("k1", "start")
    assert started.status is BrokerStatus.RUNNING
    assert [(t.name, t.partitions) for t in started.topics] == [("robot.pose", 2)]
    consumer = Consumer({"bootstrap.servers": bootstrap, "group.id": uuid.uuid4().hex,
                         "enable.auto.commit": False})
    got: list[bytes] = []
    try:
        consumer.assign([TopicPartition("robot.pose", 1, 0)])

        def all_read() -> bool:
            message = consumer.poll(0.5)
            if message is not None:
                if message.error():
                    raise KafkaException(message.error())
                got.append(message.value())
            return len(got) >= len(sent)
        process.wait_until(all_read, 60.0, 0.0, what="the messages produced before the stop")
    finally:
        consumer.close()
    assert got == sent
    client.delete_broker("k1")
    assert agent.terminate() == 0


LOOP_PLANT = """\
@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix owl: <http://www.w3.org/2002/07/owl#> .
@prefix : <http://example.org/held-plant#> .
<http://example.org/held-plant> a owl:Ontology .
:cell a pk:Broker ; pk:id "cell" ; pk:name "cell broker" ; pk:brokerType "mosquitto" ;
    pk:ip "{host}" ; pk:port {port} ; pk:hasTopic :pose ; pk:allowAnonymous true .
:pose a pk:Topic ; pk:id "pose" ; pk:name "cell/pose" ; pk:qos 1 .
"""


def test_the_reconcile_loop_leaves_a_stopped_broker_stopped(tmp_path: Path) -> None:
    from engine.agents_config import AgentDirectory  # noqa: PLC0415
    from engine.reconcile_loop import ReconcileLoop  # noqa: PLC0415
    from tests.integration.agents import start_agents  # noqa: PLC0415

    host = "127.0.0.2"
    fleet = start_agents([host], tmp_path)
    loop = None
    try:
        plant = tmp_path / "plant.ttl"
        plant.write_text(LOOP_PLANT.format(host=host, port=netutil.free_port(host)))
        directory = AgentDirectory.load(fleet.agents_file)
        runs: list = []
        loop = ReconcileLoop([plant], directory, owner="held-plant", interval=0.5,
                             on_run=runs.append)
        first = loop.run_once()
        assert first.applied and first.converged and first.summary["create"] == 2, first
        client = fleet.client(host)
        running = client.get_broker("cell")
        assert running is not None and running.status is BrokerStatus.RUNNING

        client.broker_verb("cell", "stop")
        held = loop.run_once()
        assert held.converged and not held.applied and held.error is None, held
        assert not any(held.summary.values()), held.summary
        loop.start()  # observing every 0.5 s: five runs at least, none starts it
        process.wait_until(lambda: len(runs) >= 7, 30.0, 0.05, what="five more runs of the loop")
        now = client.get_broker("cell")
        assert now is not None and now.status is BrokerStatus.STOPPED_BY_OPERATOR and now.pid is None
        assert all(r.converged and not r.applied for r in runs[1:]), runs

        started = client.broker_verb("cell", "start")
        assert started.status is BrokerStatus.RUNNING and started.pid != running.pid
        mqtt_roundtrip_on(host, started.spec.port)
    finally:
        if loop is not None:
            loop.stop()
        for broker in fleet.brokers():
            fleet.client(host).delete_broker(broker)
        fleet.stop()


def mqtt_roundtrip_on(host: str, port: int) -> None:
    """The broker on ``host`` answers an MQTT client (CONNACK)."""
    client = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"c-{uuid.uuid4().hex[:8]}")
    client.connect(host, port, keepalive=10)
    client.loop_start()
    try:
        process.wait_until(client.is_connected, 10.0, 0.005, what="CONNACK")
    finally:
        client.disconnect()
        client.loop_stop()


def test_the_dashboard_stops_and_starts_a_broker_behind_its_login(tmp_path: Path) -> None:
    from engine.agents_config import AgentDirectory  # noqa: PLC0415
    from engine.web.plant_state import PlantState  # noqa: PLC0415
    from tests.integration.agents import start_agents  # noqa: PLC0415
    from tests.web.conftest import login, make_app  # noqa: PLC0415

    host = "127.0.0.2"
    fleet = start_agents([host], tmp_path)
    state = None
    try:
        plant, port = tmp_path / "plant.ttl", netutil.free_port(host)
        plant.write_text(LOOP_PLANT.format(host=host, port=port))
        directory = AgentDirectory.load(fleet.agents_file)
        client = fleet.client(host)
        client.put_broker(BrokerSpec("cell", "http://example.org/held-plant#cell", "cell broker",
                                     "mosquitto", host, port))
        first = client.get_broker("cell")
        state = PlantState([str(plant)], fleet.agents_file, directory_loader=lambda _p: directory)
        state.reload()
        web = make_app(state).test_client()

        # Not logged in: refused, nothing stopped. Logged in without the CSRF token: refused too.
        assert web.post("/api/stop", json={"broker_id": "cell"}).status_code == 403
        csrf = login(web)
        assert web.post("/api/stop", json={"broker_id": "cell"}).status_code == 403
        assert client.get_broker("cell").status is BrokerStatus.RUNNING
        assert "<th>operator</th>" in web.get("/").get_data(as_text=True)

        with_csrf = {"X-CSRF-Token": csrf}
        stopped = web.post("/api/stop", json={"broker_id": "cell"}, headers=with_csrf)
        assert stopped.status_code == 200, stopped.json
        assert stopped.json["broker"]["status"] == "stopped-by-operator"
        assert client.get_broker("cell").status is BrokerStatus.STOPPED_BY_OPERATOR
        rows = {b["id"]: b for b in web.get("/api/status").json["brokers"]}
        assert rows["cell"]["status"] == "stopped-by-operator"

        missing = web.post("/api/start", json={"broker_id": "nope"}, headers=with_csrf)
        assert missing.status_code == 404 and "no agent reports broker 'nope'" in missing.json["error"]
        assert web.post("/api/start", json={}, headers=with_csrf).status_code == 400

        started = web.post("/api/start", json={"broker_id": "cell"}, headers=with_csrf)
        assert started.status_code == 200 and started.json["broker"]["status"] == "running"
        restarted = web.post("/api/restart", json={"broker_id": "cell"}, headers=with_csrf)
        assert restarted.status_code == 200
        assert restarted.json["broker"]["pid"] not in (first.pid, started.json["broker"]["pid"])
    finally:
        if state is not None:
            state.close()
        for broker in fleet.brokers():
            fleet.client(host).delete_broker(broker)
        fleet.stop()
