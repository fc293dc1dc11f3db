"""The MQTT <-> NGSI-v2 bridge worker against a real Mosquitto and the real context broker
(``python -m engine.context_broker``): 10,000 messages each way with nothing missing (duplicates
counted and printed), also with the worker SIGKILLed mid-stream and started again, and the context
broker SIGKILLed mid-stream and started again (read back); a topic bridged
both ways does not loop; a refused message does not block its topic; a wrong token holds messages
back until the right one is in the token file; and through a real agent, a bridge PUT with
mechanism mqtt-ngsi runs the worker, reports it with counters, and its DELETE removes the
subscription from the context broker; and ``plantkg apply`` of the AGV middleware example plant,
with two agents, bridges both ways with the context broker agent's token.

Every message carries a sequence number. MQTT -> NGSI is checked by the test's own HTTP receiver,
subscribed to the entity on the context broker (so every upsert is seen, not only the last
state); NGSI -> MQTT by an MQTT subscriber of the route's topic.
"""

from __future__ import annotations

import json
import os
import stat
import threading
import time
from collections.abc import Callable, Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import paho.mqtt.client as mqtt
import pytest
from paho.mqtt.packettypes import PacketTypes
from paho.mqtt.properties import Properties

from benchmarks import bridge_rig as rig
from benchmarks.context_broker_rig import ContextBroker, Http
from engine import netutil, process
from engine.bridge_worker.ngsi_config import NgsiDirection, NgsiRoute, NgsiWorkerConfig
from engine.bridge_worker.ngsi_subscriptions import description
from engine.bridge_worker.stats import WorkerStats, read_stats
from engine.errors import WaitTimeoutError
from engine.model import BridgeDirection, BridgeEnd, BridgeMechanism, BridgeRoute, BridgeSpec, BrokerSpec
from tests.integration.agents import start_agents

pytestmark = pytest.mark.integration

N = 10_000
RATE = 2000            # messages/s of the paced senders: the kill lands mid-stream
DEADLINE = 120.0
TOPIC = "cell/agv7"
ENTITY = ("urn:ngsi-ld:AGV:7", "AGV")


# --- receivers ----------------------------------------------------------------------------------

class NotificationReceiver:
    """An HTTP server of the test's own that the context broker notifies: the ``seq`` of every
    notified entity, in arrival order."""

    def __init__(self) -> None:
        self.seqs: list[int] = []
        receiver = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"

            def do_POST(self) -> None:  # noqa: N802 - http.server's name
                body = json.loads(self.rfile.read(int(self.headers.get("Content-Length") or 0)))
                for entity in body.get("data", []):
                    if "seq" in entity:
                        receiver.seqs.append(int(entity["seq"]))
                self.send_response(204)
                self.send_header("Content-Length", "0")
                self.end_headers()

            def log_message(self, *_: object) -> None:
                pass

        self.port = netutil.free_port("127.0.0.1")
        self.server = ThreadingHTTPServer(("127.0.0.1", self.port), Handler)
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    def subscribe(self, cb: ContextBroker) -> None:
        http = cb.http()
        body = {"description": "test receiver",
                "subject": {"entities": [{"id": ENTITY[0], "type": ENTITY[1]}]},
                "notification": {"http": {"url": f"http://127.0.0.1:{self.port}/notify"},
                                 "attrs": ["seq"], "attrsFormat": "keyValues"}}
        reply = http.request("POST", "/v2/subscriptions", json.dumps(body),
                             {**cb.auth, "Content-Type": "application/json"})
        http.close()
        assert reply.status == 201, reply.body

    def stop(self) -> None:
        self.server.shutdown()
        self.server.server_close()


class MqttCounter:
    """A persistent-session QoS-1 subscriber: the ``seq`` of every notification on ``topic``
    (and, apart, every other message)."""

    def __init__(self, port: int, topic: str, client_id: str = "test-counter", host: str = "127.0.0.1",
                 login: tuple[str, str] | None = None) -> None:
        self.seqs: list[int] = []
        self.other: list[bytes] = []
        client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=client_id, protocol=mqtt.MQTTv5)
        if login is not None:
            client.username_pw_set(*login)
        client.reconnect_delay_set(1, 1)
        client.on_message = self._message
        granted = threading.Event()
        client.on_subscribe = lambda *_: granted.set()
        props = Properties(PacketTypes.CONNECT)
        props.SessionExpiryInterval = 3600
        client.connect(host, port, clean_start=False, properties=props)
        client.subscribe(topic, qos=1)
        client.loop_start()
        process.wait_until(granted.is_set, 10.0, what="the test subscription")
        self.client = client

    def _message(self, _c: object, _u: object, msg: mqtt.MQTTMessage) -> None:
        try:
            data = json.loads(msg.payload)
            self.seqs.append(int(data["data"][0]["seq"]))
        except (ValueError, KeyError, IndexError, TypeError):
            self.other.append(bytes(msg.payload))

    def stop(self) -> None:
        self.client.disconnect()
        self.client.loop_stop()


def wait_all(seqs: list[int], count: int, what: str) -> None:
    try:
        process.wait_until(lambda: len(set(seqs)) >= count, DEADLINE, 0.05, what=what)
    except WaitTimeoutError:
        pass  # check() says what is missing


def check(label: str, seqs: list[int], count: int, *, ordered: bool = True) -> int:
    """Every sequence number 0..count-1 arrived; first arrivals in order; returns duplicates."""
    got = set(seqs)
    missing = sorted(set(range(count)) - got)
    assert not missing, f"{label}: {len(missing)} missing: {missing[:5]}...{missing[-5:]}"
    assert got <= set(range(count)), f"{label}: unexpected {sorted(got - set(range(count)))[:5]}"
    if ordered:
        firsts = list(dict.fromkeys(seqs))
        assert firsts == sorted(firsts), f"{label}: order broken"
    duplicates = len(seqs) - len(got)
    print(f"{label}: {count} sent, {len(got)} received, {duplicates} duplicates")
    return duplicates


# --- senders ------------------------------------------------------------------------------------

def publish(port: int, count: int, *, topic: str = TOPIC, rate: float | None = RATE,
            extra: Callable[[int], dict] = lambda i: {}, host: str = "127.0.0.1",
            login: tuple[str, str] | None = None) -> threading.Thread:
    """``count`` QoS-1 messages ``{"seq": i, ...}`` (paced at ``rate``/s, or as fast as they go);
    the thread ends when all are PUBACKed."""
    client = mqtt.Client(mqtt.CallbackAPIVersion.VERSION2, client_id=f"test-publisher-{topic}",
                         protocol=mqtt.MQTTv5)
    if login is not None:
        client.username_pw_set(*login)
    client.max_inflight_messages_set(100)
    client.connect(host, port)
    client.loop_start()
    pause = threading.Event()

    def run() -> None:
        start = time.monotonic()
        infos = []
        for i in range(count):
            if rate is not None and (ahead := start + i / rate - time.monotonic()) > 0.005:
                pause.wait(ahead)  # pacing the sender, not waiting for a condition
            infos.append(client.publish(topic, json.dumps({"seq": i, **extra(i)}), qos=1))
        for info in infos:
            info.wait_for_publish(60)
        client.disconnect()
        client.loop_stop()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


def update_entity(cb: ContextBroker, count: int) -> threading.Thread:
    """``count`` upserts of the entity, ``seq`` 0..count-1, paced, each answered 2xx."""
    pause = threading.Event()

    def run() -> None:
        http = cb.http()
        start = time.monotonic()
        for i in range(count):
            if (ahead := start + i / RATE - time.monotonic()) > 0.005:
                pause.wait(ahead)
            body = {"id": ENTITY[0], "type": ENTITY[1], "seq": {"type": "Number", "value": i}}
            reply = http.request("POST", "/v2/entities?options=upsert", json.dumps(body),
                                 {**cb.auth, "Content-Type": "application/json"})
            assert reply.status in (201, 204), reply.body
        http.close()

    thread = threading.Thread(target=run, daemon=True)
    thread.start()
    return thread


# --- fixtures -----------------------------------------------------------------------------------

@pytest.fixture
def cleanup() -> Iterator[list[Callable[[], object]]]:
    """Stop functions, all run in reverse order at the end (a failing one does not keep the
    others from running; the first failure is raised afterwards)."""
    todo: list[Callable[[], object]] = []
    yield todo
    failures = []
    for stop in reversed(todo):
        try:
            stop()
        except Exception as exc:  # noqa: BLE001 - re-raised below, after the rest is stopped
            failures.append(exc)
    if failures:
        raise failures[0]


@pytest.fixture
def mosquitto(tmp_path: Path, cleanup: list) -> rig.Mosquitto:
    broker = rig.Mosquitto(tmp_path / "mosquitto").start()
    cleanup.append(broker.stop)
    return broker


@pytest.fixture
def context_broker(tmp_path: Path, cleanup: list) -> ContextBroker:
    cb = ContextBroker(tmp_path / "context-broker").start()
    cleanup.append(lambda: _stopped_without_traceback(cb))
    return cb


def _stopped_without_traceback(cb: ContextBroker) -> None:
    cb.stop()
    assert "Traceback" not in cb.log_text(), cb.log_text()[-3000:]


class NgsiWorkers:
    """Starts NGSI bridge workers for a test and stops them (exit code 0) at its end."""

    def __init__(self, cleanup: list) -> None:
        self.child: process.Child | None = None
        cleanup.append(self.stop_clean)

    def config(self, tmp_path: Path, mqtt_port: int, cb: ContextBroker, *directions: NgsiDirection,
               token: str | None = None, bridge_id: str = "mqtt--cb", check_every: float = 30.0) -> NgsiWorkerConfig:
        state = tmp_path / "worker"
        state.mkdir(parents=True, exist_ok=True)
        token_file = state / "remote.token"
        token_file.write_text(cb.token if token is None else token, encoding="utf-8")
        token_file.chmod(0o600)
        routes = tuple(NgsiRoute(TOPIC, *ENTITY, d) for d in directions)
        return NgsiWorkerConfig(bridge_id, "127.0.0.1", mqtt_port, cb.url, routes, state,
                                token_file=token_file, stats_interval=0.1, check_every=check_every)

    def start(self, cfg: NgsiWorkerConfig, wait: bool = True) -> process.Child:
        self.cfg = cfg
        self.child = rig.start_worker(cfg)  # type: ignore[arg-type]  # writes worker.json, runs it
        if wait:
            rig.wait_ready(cfg, self.child)  # type: ignore[arg-type]
        return self.child

    def stats(self) -> WorkerStats | None:
        return read_stats(self.cfg.state_dir)

    def stats_reaching(self, condition: Callable[[WorkerStats], bool], deadline: float = 30.0) -> WorkerStats:
        return process.wait_until(lambda: (s := self.stats()) is not None and condition(s) and s,
                                  deadline, 0.05, what="the worker's stats to catch up", child=self.child)

    def kill_when(self, condition: Callable[[WorkerStats], bool]) -> None:
        assert self.child is not None
        self.stats_reaching(condition, 60.0)
        rig.kill_group(self.child)
        self.child = None

    def stop_clean(self) -> None:
        if self.child is not None:
            child, self.child = self.child, None
            assert process.stop(child) == 0, f"worker exit code {child.popen.returncode}: {child.log_tail()}"
            assert not child.group_alive()


@pytest.fixture
def workers(cleanup: list) -> NgsiWorkers:
    return NgsiWorkers(cleanup)


@pytest.fixture
def receiver(context_broker: ContextBroker, cleanup: list) -> NotificationReceiver:
    rec = NotificationReceiver()
    cleanup.append(rec.stop)
    rec.subscribe(context_broker)
    return rec


def our_subscriptions(cb: ContextBroker, bridge_id: str = "mqtt--cb") -> list[dict]:
    http = cb.http()
    reply = http.request("GET", "/v2/subscriptions?limit=1000", headers=cb.auth)
    http.close()
    assert reply.status == 200, reply.body
    return [s for s in reply.json() if s.get("description") == description(bridge_id, TOPIC)]


# --- MQTT -> NGSI -------------------------------------------------------------------------------

def test_mqtt_to_ngsi_10k(tmp_path: Path, mosquitto: rig.Mosquitto, context_broker: ContextBroker,
                          receiver: NotificationReceiver, workers: NgsiWorkers) -> None:
    """Unpaced: the publisher goes as fast as it can; the rate is the worker's (printed)."""
    workers.start(workers.config(tmp_path, mosquitto.port, context_broker, NgsiDirection.MQTT_TO_NGSI))
    began = time.monotonic()
    sender = publish(mosquitto.port, N, rate=None)
    stats = workers.stats_reaching(lambda s: s.forwarded_mqtt_to_ngsi >= N, DEADLINE)
    elapsed = time.monotonic() - began
    print(f"MQTT -> NGSI through the worker, QoS 1: {N} messages in {elapsed:.2f} s = {N / elapsed:.0f} msg/s")
    wait_all(receiver.seqs, N, f"{N} notifications")
    sender.join(60)
    check("mqtt->ngsi", receiver.seqs, N)
    assert stats.ready and stats.refused == 0 and stats.mechanism == "mqtt-ngsi"
    workers.stop_clean()
    assert not read_stats(workers.cfg.state_dir).ready  # type: ignore[union-attr]


def test_mqtt_to_ngsi_worker_killed(tmp_path: Path, mosquitto: rig.Mosquitto, context_broker: ContextBroker,
                                    receiver: NotificationReceiver, workers: NgsiWorkers) -> None:
    cfg = workers.config(tmp_path, mosquitto.port, context_broker, NgsiDirection.MQTT_TO_NGSI)
    workers.start(cfg)
    sender = publish(mosquitto.port, N)
    workers.kill_when(lambda s: s.forwarded_mqtt_to_ngsi >= N // 4)
    killed_at = len(set(receiver.seqs))
    workers.start(cfg)
    wait_all(receiver.seqs, N, f"{N} notifications")
    sender.join(60)
    assert killed_at < N, "the kill did not land mid-stream"
    check("mqtt->ngsi, worker killed", receiver.seqs, N)


def test_mqtt_to_ngsi_context_broker_killed(tmp_path: Path, mosquitto: rig.Mosquitto,
                                            context_broker: ContextBroker, workers: NgsiWorkers) -> None:
    """The context broker is SIGKILLed mid-stream and started again (same port, same data): the
    worker retries and goes on. Checked by reading the entity back, not by notifications (the
    context broker keeps queued notifications in memory only): message i writes attribute
    ``s<i>``, so the entity ends with every one of them. Fewer messages than the other tests: each
    upsert rewrites the entity, which grows with every message."""
    count = 1000
    workers.start(workers.config(tmp_path, mosquitto.port, context_broker, NgsiDirection.MQTT_TO_NGSI))
    sender = publish(mosquitto.port, count, rate=500, extra=lambda i: {f"s{i}": i})
    workers.stats_reaching(lambda s: s.forwarded_mqtt_to_ngsi >= count // 4, 60.0)
    assert context_broker.child is not None
    rig.kill_group(context_broker.child)
    context_broker.child = None
    stats = workers.stats_reaching(lambda s: not s.ready and s.retried > 0, 30.0)
    assert f":{context_broker.port}" in (stats.last_error or "")
    context_broker.start()
    workers.stats_reaching(lambda s: s.forwarded_mqtt_to_ngsi >= count and s.ready, DEADLINE)
    sender.join(60)
    http = context_broker.http()
    reply = http.request("GET", f"/v2/entities/{ENTITY[0]}?type={ENTITY[1]}&options=keyValues")
    http.close()
    assert reply.status == 200, reply.body
    written = {int(k[1:]) for k in reply.json() if k.startswith("s") and k[1:].isdigit()}
    missing = sorted(set(range(count)) - written)
    assert not missing, f"{len(missing)} missing: {missing[:5]}"
    print(f"mqtt->ngsi, context broker killed: {count} sent, all {len(written)} written, "
          f"{workers.stats().retried} requests retried")  # type: ignore[union-attr]


def test_a_refused_message_does_not_block_its_topic(tmp_path: Path, mosquitto: rig.Mosquitto,
                                                    context_broker: ContextBroker,
                                                    receiver: NotificationReceiver, workers: NgsiWorkers) -> None:
    workers.start(workers.config(tmp_path, mosquitto.port, context_broker, NgsiDirection.MQTT_TO_NGSI))
    # every tenth message carries a text NGSI refuses ("(" is forbidden in values)
    publish(mosquitto.port, 100, rate=None,
            extra=lambda i: {"note": "bad (value)" if i % 10 == 0 else "fine"}).join(60)
    stats = workers.stats_reaching(lambda s: s.forwarded_mqtt_to_ngsi + s.refused >= 100)
    wait_all(receiver.seqs, 90, "the 90 good messages")
    assert (stats.forwarded_mqtt_to_ngsi, stats.refused) == (90, 10)
    assert set(receiver.seqs) == {i for i in range(100) if i % 10}
    assert "refused" in (stats.last_error or "") and "'('" in (stats.last_error or "")


def test_a_wrong_token_holds_messages_until_the_right_one_is_given(
        tmp_path: Path, mosquitto: rig.Mosquitto, context_broker: ContextBroker,
        receiver: NotificationReceiver, workers: NgsiWorkers) -> None:
    cfg = workers.config(tmp_path, mosquitto.port, context_broker, NgsiDirection.MQTT_TO_NGSI,
                         token="not-the-token-3f9a")
    workers.start(cfg)  # ready: GET /version needs no token
    publish(mosquitto.port, 50, rate=None).join(60)
    stats = workers.stats_reaching(lambda s: s.retried >= 2 and not s.ready)
    assert stats.forwarded_mqtt_to_ngsi == 0 and stats.refused == 0
    assert "token" in (stats.last_error or "") and "3f9a" not in (stats.last_error or "")
    assert cfg.token_file is not None
    cfg.token_file.write_text(context_broker.token, encoding="utf-8")
    wait_all(receiver.seqs, 50, "the 50 held messages")
    check("mqtt->ngsi after the token was fixed", receiver.seqs, 50)
    assert workers.stats_reaching(lambda s: s.forwarded_mqtt_to_ngsi >= 50).ready


# --- NGSI -> MQTT -------------------------------------------------------------------------------

def test_ngsi_to_mqtt_10k(tmp_path: Path, mosquitto: rig.Mosquitto, context_broker: ContextBroker,
                          workers: NgsiWorkers, cleanup: list) -> None:
    counter = MqttCounter(mosquitto.port, TOPIC)
    cleanup.append(counter.stop)
    workers.start(workers.config(tmp_path, mosquitto.port, context_broker, NgsiDirection.NGSI_TO_MQTT))
    assert len(our_subscriptions(context_broker)) == 1
    update_entity(context_broker, N).join(DEADLINE)
    wait_all(counter.seqs, N, f"{N} notifications on MQTT")
    check("ngsi->mqtt", counter.seqs, N)


def test_ngsi_to_mqtt_worker_killed_and_restarted(tmp_path: Path, mosquitto: rig.Mosquitto,
                                                  context_broker: ContextBroker, workers: NgsiWorkers,
                                                  cleanup: list) -> None:
    """The context broker publishes by itself: a killed worker loses nothing, and the restarted
    one finds its subscription instead of adding a second (which would double every message)."""
    counter = MqttCounter(mosquitto.port, TOPIC)
    cleanup.append(counter.stop)
    cfg = workers.config(tmp_path, mosquitto.port, context_broker, NgsiDirection.NGSI_TO_MQTT)
    workers.start(cfg)
    sender = update_entity(context_broker, N)
    process.wait_until(lambda: len(counter.seqs) >= N // 4, 60.0, what="a quarter delivered")
    assert workers.child is not None
    rig.kill_group(workers.child)
    workers.start(cfg)
    assert len(our_subscriptions(context_broker)) == 1
    sender.join(DEADLINE)
    wait_all(counter.seqs, N, f"{N} notifications on MQTT")
    assert check("ngsi->mqtt, worker killed", counter.seqs, N) == 0


def test_a_subscription_deleted_by_someone_else_is_made_again(
        tmp_path: Path, mosquitto: rig.Mosquitto, context_broker: ContextBroker, workers: NgsiWorkers,
        cleanup: list) -> None:
    counter = MqttCounter(mosquitto.port, TOPIC)
    cleanup.append(counter.stop)
    workers.start(workers.config(tmp_path, mosquitto.port, context_broker, NgsiDirection.NGSI_TO_MQTT,
                                 check_every=0.5))
    [sub] = our_subscriptions(context_broker)
    http = context_broker.http()
    assert http.request("DELETE", f"/v2/subscriptions/{sub['id']}", headers=context_broker.auth).status == 204
    [again] = process.wait_until(lambda: our_subscriptions(context_broker) or None, 30.0, 0.1,
                                 what="the subscription made again")
    assert again["id"] != sub["id"]
    update_entity(context_broker, 1).join(30)
    process.wait_until(lambda: counter.seqs == [0], 30.0, 0.05, what="the update on MQTT")
    http.close()


# --- both ways ----------------------------------------------------------------------------------

def test_a_topic_bridged_both_ways_does_not_loop(tmp_path: Path, mosquitto: rig.Mosquitto,
                                                 context_broker: ContextBroker,
                                                 receiver: NotificationReceiver, workers: NgsiWorkers,
                                                 cleanup: list) -> None:
    """Each MQTT message is written once; the context broker publishes the change back on the
    same topic, and the worker skips that notification instead of writing it again."""
    counter = MqttCounter(mosquitto.port, TOPIC)
    cleanup.append(counter.stop)
    workers.start(workers.config(tmp_path, mosquitto.port, context_broker, NgsiDirection.MQTT_TO_NGSI,
                                 NgsiDirection.NGSI_TO_MQTT))
    publish(mosquitto.port, 200, rate=None).join(60)
    workers.stats_reaching(lambda s: s.skipped >= 200, 60.0)
    # one more, written by someone else on the context broker: out to MQTT, and not back in
    http = context_broker.http()
    reply = http.request("POST", "/v2/entities?options=upsert",
                         json.dumps({"id": ENTITY[0], "type": ENTITY[1], "seq": {"type": "Number", "value": 200}}),
                         {**context_broker.auth, "Content-Type": "application/json"})
    http.close()
    assert reply.status in (201, 204)
    stats = workers.stats_reaching(lambda s: s.skipped >= 201, 60.0)
    wait_all(counter.seqs, 201, "201 notifications on MQTT")
    assert stats.forwarded_mqtt_to_ngsi == 200, "a notification was written back: a loop"
    assert sorted(counter.seqs) == list(range(201))           # each change published once
    assert len(counter.other) == 200                          # and the raw messages themselves
    wait_all(receiver.seqs, 201, "201 HTTP notifications")    # a lane of their own: they may lag MQTT's
    assert sorted(receiver.seqs) == list(range(201))          # each written once


# --- through a real agent -----------------------------------------------------------------------

def test_agent_runs_an_ngsi_bridge(tmp_path: Path, context_broker: ContextBroker,
                                   receiver: NotificationReceiver) -> None:
    fleet = start_agents(["127.0.0.1"], tmp_path / "agents")
    try:
        agent = fleet.client("127.0.0.1")
        port = netutil.free_port("127.0.0.1")
        agent.put_broker(BrokerSpec("mqtt", "urn:test:mqtt", "MQTT", "mosquitto", "127.0.0.1", port))
        route = BridgeRoute(TOPIC, BridgeDirection.BOTH, 1, entity_id=ENTITY[0], entity_type=ENTITY[1])
        spec = BridgeSpec(BridgeEnd("mqtt", "mosquitto", "127.0.0.1", port),
                          BridgeEnd("cb", "ngsi-v2", "127.0.0.1", context_broker.port),
                          BridgeMechanism.NGSI, (route,))
        first = agent.put_bridge(spec, remote_token=context_broker.token)
        again = agent.put_bridge(spec, remote_token=context_broker.token)
        assert again.pid == first.pid, "a repeated PUT restarted the worker"
        rotated = agent.put_bridge(spec, remote_token="another-token")
        assert rotated.pid != first.pid, "a new token did not restart the worker"
        restored = agent.put_bridge(spec, remote_token=context_broker.token)
        assert restored.pid != rotated.pid

        def running(forwarded: int) -> Callable[[], object]:
            def check_once() -> object:
                bridges = [b for b in agent.list_bridges() if b.spec.address == spec.address]
                return bridges and bridges[0].status.value == "running" \
                    and (bridges[0].forwarded or 0) >= forwarded and bridges[0]
            return check_once

        # subscribed before anything is published: the worker's session starts with its first run
        process.wait_until(running(0), 30.0, 0.2, what="the bridge running")
        publish(port, 100, rate=None).join(60)
        wait_all(receiver.seqs, 100, "100 notifications")
        check("through the agent", receiver.seqs, 100)
        bridge = process.wait_until(running(100), 30.0, 0.2, what="the bridge running with its counters")
        assert bridge.spec == spec and bridge.retried == 0 and bridge.refused == 0
        publish(port, 1, rate=None, extra=lambda i: {"note": "a=b"}).join(60)  # "=" is refused
        process.wait_until(lambda: [b.refused for b in agent.list_bridges()] == [1], 30.0, 0.2,
                           what="the refused message counted")
        assert len(our_subscriptions(context_broker, "mqtt--cb")) == 1

        folder = fleet.agents["127.0.0.1"].state_dir / "bridges" / "mqtt--cb"
        token_file = folder / "remote.token"
        assert stat.S_IMODE(token_file.stat().st_mode) == 0o600
        for name in ("spec.json", "worker.json", "pid.json", "stats.json", "logs/bridge.log"):
            assert context_broker.token not in (folder / name).read_text(), name

        agent_log = (tmp_path / "agents" / "logs" / "agent-127.0.0.1.log").read_text()
        assert context_broker.token not in agent_log

        agent.delete_bridge("mqtt", "cb")
        assert our_subscriptions(context_broker, "mqtt--cb") == []
        assert not folder.exists() and not any(
            p.name == "remote.token" for p in (fleet.agents["127.0.0.1"].state_dir / "removed").rglob("*"))
        agent.delete_broker("mqtt")
    finally:
        fleet.stop()


# --- the whole path: plant -> plan -> apply -> agents -> worker ----------------------------------

def test_apply_of_the_agv_middleware_plant_bridges_mqtt_and_the_context_broker(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The example plant: Mosquitto on 127.0.0.2, the context broker on 127.0.0.3, each with its
    agent. ``plantkg apply`` sends the context broker agent's token with the bridge; the AGV's
    status written on MQTT reaches its entity, a motion command written on the context broker
    reaches MQTT; ``plantkg status`` shows the bridge running; no token in the plan or status."""
    from engine.cli import main
    from tests.integration.agents import plant_copy

    plant, _ = plant_copy("agv-middleware.ttl", tmp_path)
    fleet = start_agents(["127.0.0.2", "127.0.0.3"], tmp_path / "agents")
    agents = ["--agents", str(fleet.agents_file)]
    try:
        assert main(["apply", str(plant), *agents, "--yes"]) == 0, capsys.readouterr()
        [mqtt_port] = [b.spec.port for b in fleet.client("127.0.0.2").list_brokers()]
        [cb_port] = [b.spec.port for b in fleet.client("127.0.0.3").list_brokers()]
        bridge = process.wait_until(
            lambda: [b for b in fleet.client("127.0.0.2").list_bridges()
                     if b.spec.mechanism is BridgeMechanism.NGSI and b.status.value == "running"],
            60.0, 0.2, what="the mqtt-ngsi bridge running")[0]
        assert bridge.spec.remote.port == cb_port
        worker_dir = fleet.agents["127.0.0.2"].state_dir / "bridges" / "fleet-mqtt--fleet-context"
        cb_token = fleet.agents["127.0.0.3"].token
        assert (worker_dir / "remote.token").read_text() == cb_token
        capsys.readouterr()
        assert main(["plan", str(plant), *agents]) == 0
        assert cb_token not in capsys.readouterr().out

        # the plant's Mosquitto is closed: the AGV interface publishes its status and reads its
        # motion commands with its own password (tests/conftest.py made a throwaway one)
        agv = ("agv-interface-1", os.environ["PLANTKG_AGV_INTERFACE_1_PASSWORD"])
        counter = MqttCounter(mqtt_port, "agv-1/motion_channel", "test-motion", host="127.0.0.2", login=agv)
        try:
            publish(mqtt_port, 1, topic="agv-1/status_channel", rate=None, host="127.0.0.2",
                    extra=lambda i: {"state": "idle", "battery": 87}, login=agv).join(30)
            http = Http("127.0.0.3", cb_port)  # the context broker the agent runs

            def status_entity() -> dict | None:
                reply = http.request("GET", "/v2/entities/urn:ngsi-ld:AGV:agv-1?type=AGV&options=keyValues",
                                     headers={"Authorization": f"Bearer {cb_token}"})  # closed: reads too
                return reply.json() if reply.status == 200 else None
            entity = process.wait_until(status_entity, 30.0, 0.1, what="the AGV entity")
            assert (entity["state"], entity["battery"], entity["seq"]) == ("idle", 87, 0)

            body = {"id": "urn:ngsi-ld:MotionCommand:agv-1", "type": "MotionCommand",
                    "seq": {"type": "Number", "value": 0}}
            reply = http.request("POST", "/v2/entities?options=upsert", json.dumps(body),
                                 {"Authorization": f"Bearer {cb_token}", "Content-Type": "application/json"})
            http.close()
            assert reply.status in (201, 204), reply.body
            process.wait_until(lambda: counter.seqs == [0], 30.0, 0.05, what="the motion command on MQTT")
        finally:
            counter.stop()

        capsys.readouterr()
        assert main(["status", str(plant), *agents]) == 0
        table = capsys.readouterr().out
        line = next(row for row in table.splitlines() if "bridge.fleet-mqtt.fleet-context" in row)
        assert "mqtt-ngsi" in line and "running" in line and cb_token not in table

        assert main(["destroy", str(plant), *agents, "--yes"]) == 0
    finally:
        fleet.stop()
