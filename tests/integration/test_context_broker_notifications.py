"""Subscriptions and notifications end to end, with real receivers.

Most tests create a subscription over real HTTP (the subscription blueprint in a Flask app
served by Werkzeug on a free port) and hand entity changes to the service as the entity layer
does (``entity_changed``), so a test can shape the changes exactly; what arrives is checked at
real receivers: a small HTTP server in the test, a real Mosquitto (a paho subscriber), a real
Kafka (a consumer). A receiver that is down for a few seconds gets every notification
afterwards, in order, with the outage shown on the subscription; a receiver that hangs does not
delay another subscription. The last tests go through the real server process
(``python -m engine.context_broker``, with its write token) driven by FiLiP: subscriptions
posted, read and deleted, entity writes notified to an HTTP receiver and an MQTT subscriber,
and subscriptions surviving a kill -9.
"""

from __future__ import annotations

import json
import queue
import threading
import time
import urllib.request
import uuid
from collections.abc import Callable, Iterator
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import paho.mqtt.client as mqtt
import pytest
from confluent_kafka import Consumer, KafkaException, TopicPartition
from confluent_kafka.admin import AdminClient, NewTopic
from flask import Flask
from paho.mqtt.enums import CallbackAPIVersion
from werkzeug.serving import make_server

from benchmarks import bridge_rig as rig
from engine import netutil, process
from engine.context_broker.contract import EntityChange, Tenant
from engine.context_broker.subscriptions import SubscriptionService

pytestmark = pytest.mark.integration

HOST = "127.0.0.1"
ACME = Tenant("acme", "/plant")


# --- an HTTP receiver ----------------------------------------------------------------------

class Receiver:
    """Records every request (method, path with query, headers, JSON body). ``hang``: each
    request waits for :attr:`release` before the 200."""

    def __init__(self, port: int | None = None, hang: bool = False) -> None:
        self.port = port or netutil.free_port(HOST)
        self.hang = hang
        self.release = threading.Event()
        self.requests: list[dict[str, Any]] = []
        self.lock = threading.Lock()
        self.server: ThreadingHTTPServer | None = None

    @property
    def url(self) -> str:
        return f"http://{HOST}:{self.port}/notify"

    def start(self) -> Receiver:
        receiver = self

        class Handler(BaseHTTPRequestHandler):
            protocol_version = "HTTP/1.1"  # keep-alive, as most receivers

            def do_POST(self) -> None:  # noqa: N802 (http.server's naming)
                body = self.rfile.read(int(self.headers.get("Content-Length", 0)))
                if receiver.hang:
                    receiver.release.wait(30)
                with receiver.lock:
                    receiver.requests.append({"method": "POST", "path": self.path,
                                              "headers": dict(self.headers), "body": json.loads(body)})
                self.send_response(200)
                self.send_header("Content-Length", "0")
                self.end_headers()

            def log_message(self, *args: Any) -> None:
                return None

        self.server = ThreadingHTTPServer((HOST, self.port), Handler)
        self.server.daemon_threads = True
        threading.Thread(target=self.server.serve_forever, daemon=True).start()
        return self

    def stop(self) -> None:
        self.release.set()
        if self.server is not None:
            self.server.shutdown()
            self.server.server_close()

    def values(self, attr: str = "temperature") -> list[Any]:
        with self.lock:
            out = []
            for r in self.requests:
                a = r["body"]["data"][0][attr]
                out.append(a["value"] if isinstance(a, dict) else a)
            return out


# --- the broker side -------------------------------------------------------------------------

class Broker:
    """The subscription service behind real HTTP; ``change`` plays the entity layer."""

    def __init__(self, data_dir: Path) -> None:
        self.service = SubscriptionService(data_dir)
        self.service.start()
        app = Flask("context-broker-test")
        app.register_blueprint(self.service.blueprint())
        self.port = netutil.free_port(HOST)
        self.server = make_server(HOST, self.port, app, threaded=True)
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)
        self.thread.start()

    def call(self, method: str, path: str, body: Any = None, tenant: Tenant = ACME) -> tuple[int, dict[str, str], Any]:
        headers = {"Fiware-Service": tenant.service, "Fiware-ServicePath": tenant.service_path}
        data = None
        if body is not None:
            data = json.dumps(body).encode()
            headers["Content-Type"] = "application/json"
        req = urllib.request.Request(f"http://{HOST}:{self.port}{path}", data=data, method=method,
                                     headers=headers)
        try:
            with urllib.request.urlopen(req, timeout=10) as resp:
                raw = resp.read()
                return resp.status, dict(resp.headers), json.loads(raw) if raw else None
        except urllib.error.HTTPError as err:
            return err.code, dict(err.headers), json.loads(err.read() or b"null")

    def subscribe(self, doc: dict[str, Any], tenant: Tenant = ACME) -> str:
        status, headers, _ = self.call("POST", "/v2/subscriptions", doc, tenant)
        assert status == 201, (status, headers)
        return headers["Location"].rsplit("/", 1)[1]

    def show(self, sub_id: str) -> dict[str, Any]:
        status, _, body = self.call("GET", f"/v2/subscriptions/{sub_id}")
        assert status == 200, body
        return body

    def change(self, temperature: Any, entity_id: str = "AGV1", tenant: Tenant = ACME, **more: Any) -> None:
        entity = {"id": entity_id, "type": "AGV",
                  "temperature": {"type": "Number", "value": temperature, "metadata": {}}}
        for name, value in more.items():
            entity[name] = {"type": "Text", "value": value, "metadata": {}}
        self.service.entity_changed(EntityChange(tenant, entity, frozenset(entity) - {"id", "type"}))

    def close(self) -> None:
        self.server.shutdown()
        self.service.close()


@pytest.fixture
def cleanup() -> Iterator[list[Callable[[], object]]]:
    todo: list[Callable[[], object]] = []
    yield todo
    for stop in reversed(todo):
        stop()


@pytest.fixture
def broker(tmp_path: Path, cleanup: list) -> Broker:
    b = Broker(tmp_path / "cb")
    cleanup.append(b.close)
    return b


def receiver(cleanup: list, **kwargs: Any) -> Receiver:
    r = Receiver(**kwargs).start()
    cleanup.append(r.stop)
    return r


def wait_for(predicate: Callable[[], Any], what: str, deadline: float = 20.0) -> Any:
    return process.wait_until(predicate, deadline, 0.02, what=what)


def shown_when(broker: Broker, sub_id: str, check: Callable[[dict[str, Any]], bool], what: str,
               deadline: float = 20.0) -> dict[str, Any]:
    """Poll GET /v2/subscriptions/{id} until ``check`` holds; return that view."""
    def poll() -> dict[str, Any] | None:
        view = broker.show(sub_id)
        return view if check(view) else None
    return wait_for(poll, what, deadline)


def subject(**condition: Any) -> dict[str, Any]:
    out: dict[str, Any] = {"entities": [{"idPattern": "^AGV", "type": "AGV"}]}
    if condition:
        out["condition"] = condition
    return out


# --- tests -----------------------------------------------------------------------------------

def test_http_notification_is_orions(broker: Broker, cleanup: list) -> None:
    rec = receiver(cleanup)
    other = receiver(cleanup)
    sub_id = broker.subscribe({
        "description": "AGV temperature",
        "subject": subject(attrs=["temperature"], expression={"q": "mode==driving"}),
        "notification": {"httpCustom": {"url": rec.url, "headers": {"X-Plant": "kit"}, "qs": {"token": "a b"}},
                         "attrs": ["temperature", "mode"], "attrsFormat": "keyValues"},
    })
    broker.subscribe({"subject": {"entities": [{"id": "AGV9"}]}, "notification": {"http": {"url": other.url}}})
    assert rec.requests == []                       # no initial notification
    broker.change(41, mode="parked")                # q does not match
    broker.change(42, mode="driving")
    wait_for(lambda: broker.show(sub_id)["notification"].get("timesSent") == 1, "one notification sent")
    wait_for(lambda: len(rec.requests) == 1, "the notification at the receiver")
    [req] = rec.requests
    assert req["body"] == {"subscriptionId": sub_id,
                           "data": [{"id": "AGV1", "type": "AGV", "temperature": 42, "mode": "driving"}]}
    assert req["path"] == "/notify?token=a+b"
    headers = {k.lower(): v for k, v in req["headers"].items()}
    assert headers["content-type"] == "application/json"
    assert headers["ngsiv2-attrsformat"] == "keyValues"
    assert (headers["fiware-service"], headers["fiware-servicepath"]) == ("acme", "/plant")
    assert headers["x-plant"] == "kit" and headers["fiware-correlator"]
    shown = broker.show(sub_id)["notification"]
    assert shown["lastSuccessCode"] == 200 and "lastSuccess" in shown and "failsCounter" not in shown
    assert other.requests == []


def test_receiver_down_for_a_while_gets_everything_in_order(broker: Broker, cleanup: list) -> None:
    port = netutil.free_port(HOST)
    url = f"http://{HOST}:{port}/notify"
    sub_id = broker.subscribe({"subject": subject(), "notification": {"http": {"url": url}}})
    for t in range(1, 6):
        broker.change(t)
    shown = shown_when(broker, sub_id, lambda v: v["notification"].get("failsCounter", 0) >= 3,
                       "three failed attempts")
    assert shown["status"] == "failed"
    assert shown["notification"]["lastFailureReason"].startswith("Couldn't connect to server")
    outage_started = time.monotonic()
    broker.change(6)                                 # queued behind the failing one
    rec = receiver(cleanup, port=port)               # the receiver comes back
    wait_for(lambda: len(rec.requests) >= 6, "every notification after the outage", deadline=40.0)
    recovery = time.monotonic() - outage_started
    assert rec.values() == [1, 2, 3, 4, 5, 6]
    after = broker.show(sub_id)
    assert after["status"] == "active" and "failsCounter" not in after["notification"]
    assert "lastFailure" in after["notification"] and after["notification"]["lastSuccessCode"] == 200
    assert after["notification"]["timesSent"] >= 6 + 3
    assert recovery < 35.0  # the backoff is capped at 30 s


def test_a_hanging_receiver_does_not_delay_another_subscription(broker: Broker, cleanup: list) -> None:
    hanging = receiver(cleanup, hang=True)
    fine = receiver(cleanup)
    # The hanging receiver times out after 4 s: the healthy one must have all three before that,
    # i.e. while the hanging subscription shows no failure yet (an order, not a time bound).
    slow_id = broker.subscribe({"subject": subject(), "notification": {"http": {"url": hanging.url, "timeout": 4000}}})
    broker.subscribe({"subject": subject(), "notification": {"http": {"url": fine.url}}})
    for t in (1, 2, 3):
        broker.change(t)
    seen: list[tuple[int, int]] = []  # (healthy notifications, then the hanging one's failures)

    def settled() -> bool:
        seen.append((len(fine.requests), broker.show(slow_id)["notification"].get("failsCounter", 0)))
        return seen[-1][0] == 3 or seen[-1][1] >= 1
    wait_for(settled, "the other subscription's notifications", deadline=20.0)
    assert seen[-1] == (3, 0), f"the healthy receiver waited for the hanging one's timeout: {seen[-1]}"
    assert fine.values() == [1, 2, 3]
    wait_for(lambda: broker.show(slow_id)["notification"].get("failsCounter", 0) >= 1, "a timeout on the hanging one")
    assert broker.show(slow_id)["notification"]["lastFailureReason"].startswith("Timeout was reached")
    hanging.release.set()
    wait_for(lambda: broker.show(slow_id)["status"] == "active"
             and broker.show(slow_id)["notification"].get("lastSuccessCode") == 200
             and _dedup(hanging.values())[-1:] == [3], "the hanging receiver catching up")
    assert _dedup(hanging.values()) == [1, 2, 3]   # at least once: a timed-out request may arrive twice


def _dedup(values: list[Any]) -> list[Any]:
    return [v for i, v in enumerate(values) if i == 0 or values[i - 1] != v]


def test_mqtt_notification(broker: Broker, tmp_path: Path, cleanup: list) -> None:
    mosq = rig.Mosquitto(tmp_path / "mosquitto").start()
    cleanup.append(mosq.stop)
    got: queue.Queue[mqtt.MQTTMessage] = queue.Queue()
    sub = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"test-{uuid.uuid4().hex[:8]}")
    subscribed = threading.Event()
    sub.on_message = lambda _c, _u, msg: got.put(msg)
    sub.on_subscribe = lambda *_args: subscribed.set()
    sub.connect(HOST, mosq.port)
    sub.loop_start()
    cleanup.append(sub.loop_stop)
    cleanup.append(sub.disconnect)
    wait_for(sub.is_connected, "the test subscriber to connect")
    topic = "plant/agv/state"
    sub.subscribe(topic, qos=1)
    assert subscribed.wait(10), "no SUBACK"
    sub_id = broker.subscribe({
        "subject": subject(),
        "notification": {"mqtt": {"url": f"mqtt://{HOST}:{mosq.port}", "topic": topic, "qos": 1},
                         "attrs": ["temperature"]},
    })
    broker.change(7)
    msg = got.get(timeout=20)
    assert msg.topic == topic and msg.qos == 1
    assert json.loads(msg.payload) == {"subscriptionId": sub_id, "data": [
        {"id": "AGV1", "type": "AGV", "temperature": {"type": "Number", "value": 7, "metadata": {}}}]}
    for t in (8, 9):
        broker.change(t)
    values = [json.loads(got.get(timeout=20).payload)["data"][0]["temperature"]["value"] for _ in range(2)]
    assert values == [8, 9]
    shown = shown_when(broker, sub_id, lambda v: v["notification"].get("timesSent") == 3,
                       "three MQTT notifications counted")
    assert shown["status"] == "active" and "lastSuccess" in shown["notification"]
    assert "lastSuccessCode" not in shown["notification"]


def test_mqtt_broker_down_then_up(broker: Broker, tmp_path: Path, cleanup: list) -> None:
    mosq = rig.Mosquitto(tmp_path / "mosquitto")   # configured on a free port, not started yet
    topic = "plant/agv/late"
    sub_id = broker.subscribe({"subject": subject(),
                               "notification": {"mqtt": {"url": f"mqtt://{HOST}:{mosq.port}", "topic": topic,
                                                         "qos": 1, "retain": True}}})
    broker.change(1)
    wait_for(lambda: broker.show(sub_id)["notification"].get("failsCounter", 0) >= 1, "a failed MQTT attempt")
    failing = broker.show(sub_id)
    assert failing["status"] == "failed"
    assert failing["notification"]["lastFailureReason"] == (
        f"MQTT broker {HOST}:{mosq.port} not connected (connection refused or unreachable)")
    mosq.start()
    cleanup.append(mosq.stop)
    wait_for(lambda: broker.show(sub_id)["status"] == "active", "delivery once Mosquitto is up", deadline=40.0)
    got: queue.Queue[mqtt.MQTTMessage] = queue.Queue()
    late = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"late-{uuid.uuid4().hex[:8]}")
    late.on_message = lambda _c, _u, msg: got.put(msg)
    late.on_connect = lambda c, _u, _f, _rc, _p: c.subscribe(topic, qos=1)
    late.connect(HOST, mosq.port)
    late.loop_start()
    cleanup.append(late.loop_stop)
    cleanup.append(late.disconnect)
    msg = got.get(timeout=20)                        # retained, so a late subscriber sees it
    assert msg.retain and json.loads(msg.payload)["data"][0]["temperature"]["value"] == 1


def test_kafka_notification(broker: Broker, kafka_broker) -> None:
    bootstrap = kafka_broker.bootstrap_servers
    admin = AdminClient({"bootstrap.servers": bootstrap})
    process.wait_until(lambda: admin.list_topics(timeout=2).brokers, 90.0, 0.2,
                       what=f"Kafka metadata from {bootstrap}", ignore=(KafkaException,))
    topic = f"plantkg-notify-{uuid.uuid4().hex[:8]}"
    admin.create_topics([NewTopic(topic, num_partitions=1, replication_factor=1)])[topic].result(timeout=30)
    sub_id = broker.subscribe({"subject": subject(),
                               "notification": {"kafka": {"url": f"kafka://{bootstrap}", "topic": topic},
                                                "attrsFormat": "keyValues"}})
    broker.change(1, entity_id="AGV1")
    broker.change(2, entity_id="AGV2")
    broker.change(3, entity_id="AGV1")
    consumer = Consumer({"bootstrap.servers": bootstrap, "group.id": f"test-{uuid.uuid4().hex[:8]}",
                         "enable.auto.commit": False})
    try:
        consumer.assign([TopicPartition(topic, 0, 0)])
        records = []

        def three() -> bool:
            msg = consumer.poll(0.5)
            if msg is not None:
                if msg.error():
                    raise KafkaException(msg.error())
                records.append(msg)
            return len(records) >= 3

        wait_for(three, "three notification records", deadline=60.0)
    finally:
        consumer.close()
    assert [(r.key(), json.loads(r.value())) for r in records] == [
        (b"AGV1", {"subscriptionId": sub_id, "data": [{"id": "AGV1", "type": "AGV", "temperature": 1}]}),
        (b"AGV2", {"subscriptionId": sub_id, "data": [{"id": "AGV2", "type": "AGV", "temperature": 2}]}),
        (b"AGV1", {"subscriptionId": sub_id, "data": [{"id": "AGV1", "type": "AGV", "temperature": 3}]}),
    ]
    headers = dict(records[0].headers())
    assert headers["Ngsiv2-AttrsFormat"] == b"keyValues" and headers["Fiware-Service"] == b"acme"
    assert headers["Fiware-ServicePath"] == b"/plant"
    shown = shown_when(broker, sub_id, lambda v: v["notification"].get("timesSent") == 3,
                       "three Kafka notifications counted")
    assert shown["status"] == "active"


# --- through the server process, driven by FiLiP ---------------------------------------------

@pytest.fixture
def server(tmp_path: Path, cleanup: list):
    from benchmarks.context_broker_rig import ContextBroker

    cb = ContextBroker(tmp_path / "context-broker").start()
    cleanup.append(cb.stop)
    return cb


def filip_client(server: Any, tenant: Tenant = ACME) -> Any:
    import requests
    from filip.clients.ngsi_v2 import ContextBrokerClient
    from filip.models.base import FiwareHeader

    session = requests.Session()
    session.headers.update(server.auth)          # writes need the broker's token
    return ContextBrokerClient(url=server.url, session=session,
                               fiware_header=FiwareHeader(service=tenant.service,
                                                          service_path=tenant.service_path))


def test_filip_end_to_end_through_the_server(server: Any, tmp_path: Path, cleanup: list) -> None:
    from filip.clients.exceptions import BaseHttpClientException
    from filip.models.ngsi_v2.context import ContextEntity
    from filip.models.ngsi_v2.subscriptions import Subscription

    rec = receiver(cleanup)
    mosq = rig.Mosquitto(tmp_path / "mosquitto").start()
    cleanup.append(mosq.stop)
    got: queue.Queue[mqtt.MQTTMessage] = queue.Queue()
    subscribed = threading.Event()
    listener = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"e2e-{uuid.uuid4().hex[:8]}")
    listener.on_message = lambda _c, _u, msg: got.put(msg)
    listener.on_subscribe = lambda *_args: subscribed.set()
    listener.on_connect = lambda c, *_args: c.subscribe("fleet/agv", qos=1)
    listener.connect(HOST, mosq.port)
    listener.loop_start()
    cleanup.append(listener.loop_stop)
    cleanup.append(listener.disconnect)
    assert subscribed.wait(10), "no SUBACK from Mosquitto"

    cb = filip_client(server)
    http_sub = Subscription(
        description="AGV state to the MES",
        subject={"entities": [{"idPattern": "^AGV", "type": "AGV"}], "condition": {"attrs": ["state"]}},
        notification={"http": {"url": rec.url}, "attrs": ["state", "battery"]},
    )
    http_id = cb.post_subscription(http_sub)             # FiLiP lists subscriptions first
    with pytest.warns(UserWarning, match="existed already"):
        assert cb.post_subscription(http_sub) == http_id  # ... and so does not post it twice
    mqtt_id = cb.post_subscription(Subscription(
        subject={"entities": [{"id": "AGV1", "type": "AGV"}]},
        notification={"mqtt": {"url": f"mqtt://{HOST}:{mosq.port}", "topic": "fleet/agv", "qos": 1},
                      "attrsFormat": "keyValues"},
    ))
    assert len({http_id, mqtt_id}) == 2 and all(len(i) == 24 for i in (http_id, mqtt_id))
    fetched = cb.get_subscription(http_id)
    assert fetched.id == http_id and fetched.description == "AGV state to the MES"
    assert str(fetched.notification.http.url).rstrip("/") == rec.url
    assert rec.requests == [] and got.empty()            # no initial notification

    cb.post_entity(ContextEntity(id="AGV1", type="AGV", state={"type": "Text", "value": "idle"},
                                 battery={"type": "Number", "value": 80}))
    cb.update_attribute_value(entity_id="AGV1", attr_name="state", value="moving", entity_type="AGV")
    wait_for(lambda: len(rec.requests) == 2, "two HTTP notifications (create, update)")
    assert rec.values("state") == ["idle", "moving"]
    assert rec.requests[1]["body"] == {"subscriptionId": http_id, "data": [{
        "id": "AGV1", "type": "AGV",
        "state": {"type": "Text", "value": "moving", "metadata": {}},
        "battery": {"type": "Number", "value": 80, "metadata": {}}}]}
    headers = {k.lower(): v for k, v in rec.requests[1]["headers"].items()}
    assert (headers["fiware-service"], headers["fiware-servicepath"]) == ("acme", "/plant")
    payloads = [json.loads(got.get(timeout=20).payload) for _ in range(2)]
    assert payloads == [
        {"subscriptionId": mqtt_id, "data": [{"id": "AGV1", "type": "AGV", "state": "idle", "battery": 80}]},
        {"subscriptionId": mqtt_id, "data": [{"id": "AGV1", "type": "AGV", "state": "moving", "battery": 80}]},
    ]

    cb.delete_subscription(http_id)
    with pytest.raises(BaseHttpClientException) as info:
        cb.get_subscription(http_id)
    assert info.value.response.status_code == 404
    cb.update_attribute_value(entity_id="AGV1", attr_name="state", value="charging", entity_type="AGV")
    third = json.loads(got.get(timeout=20).payload)       # the MQTT one still fires ...
    assert third["data"][0]["state"] == "charging"
    assert len(rec.requests) == 2                         # ... the deleted one does not
    assert [s.id for s in cb.get_subscription_list()] == [mqtt_id]


def test_subscriptions_survive_kill_9_of_the_server(server: Any) -> None:
    from benchmarks.context_broker_rig import ContextBroker

    from filip.models.ngsi_v2.subscriptions import Subscription

    cb = filip_client(server)
    sub_id = cb.post_subscription(Subscription(
        subject={"entities": [{"id": "AGV1"}]}, notification={"http": {"url": "http://127.0.0.1:9/n"}}))
    rig.kill_group(server.child)                          # SIGKILL right after the 201
    server.child = None
    again = ContextBroker(server.folder, port=server.port, token=server.token).start()
    try:
        shown = filip_client(again).get_subscription(sub_id)
        assert shown.id == sub_id and str(shown.notification.http.url).rstrip("/") == "http://127.0.0.1:9/n"
    finally:
        again.stop()


def test_kafka_down_then_up_gets_every_notification_in_order(broker: Broker, tmp_path: Path, cleanup: list) -> None:
    from tests.integration.conftest import start_kafka

    kafka = start_kafka(tmp_path / "own-kafka")
    children = [kafka.child]
    cleanup.append(lambda: [process.stop(c, grace=30.0) for c in children if c is not None])
    topic = "agv.state"
    rig.create_topics(kafka.bootstrap_servers, [topic])
    process.stop(kafka.child, grace=30.0)                 # the receiver is down ...
    children.clear()
    sub_id = broker.subscribe({"subject": subject(),
                               "notification": {"kafka": {"url": f"kafka://{kafka.bootstrap_servers}",
                                                          "topic": topic}, "attrsFormat": "keyValues"}})
    for t in (1, 2, 3):
        broker.change(t)
    failing = shown_when(broker, sub_id, lambda v: v["notification"].get("failsCounter", 0) >= 1,
                         "a failed Kafka attempt", deadline=40.0)
    assert failing["status"] == "failed" and "Kafka" in failing["notification"]["lastFailureReason"]
    children.append(rig.respawn_kafka(kafka.config, kafka.broker_dir))   # ... and back
    shown_when(broker, sub_id, lambda v: v["status"] == "active" and v["notification"].get("lastSuccess"),
               "delivery once Kafka is back", deadline=90.0)
    consumer = Consumer({"bootstrap.servers": kafka.bootstrap_servers,
                         "group.id": f"test-{uuid.uuid4().hex[:8]}", "enable.auto.commit": False})
    values: list[Any] = []
    try:
        consumer.assign([TopicPartition(topic, 0, 0)])

        def three() -> bool:
            msg = consumer.poll(0.5)
            if msg is not None and not msg.error():
                values.append(json.loads(msg.value())["data"][0]["temperature"])
            return len(values) >= 3

        wait_for(three, "the three notifications in Kafka", deadline=60.0)
    finally:
        consumer.close()
    assert _dedup(values) == [1, 2, 3]   # at least once: a timed-out produce may be written twice


def test_notifications_of_answered_writes_survive_kill_9_of_the_server(server: Any, cleanup: list) -> None:
    """The receiver is down while 200 writes are answered 204; the context broker is SIGKILLed,
    started again on the same folder, the receiver comes up: every one of the 200 notifications
    arrives, in order (the outbox; delivery is at least once, so a repeat would be allowed, a gap
    never). Then a clean stop with the receiver down again: what was queued is sent after the
    next start too."""
    from benchmarks.context_broker_rig import ContextBroker

    port = netutil.free_port(HOST)
    url = f"http://{HOST}:{port}/notify"
    http = server.http()
    headers = {"Content-Type": "application/json", "Fiware-Service": ACME.service,
               "Fiware-ServicePath": ACME.service_path, **server.auth}
    reply = http.request("POST", "/v2/subscriptions", json.dumps({
        "subject": {"entities": [{"id": "AGV1", "type": "AGV"}]},
        "notification": {"http": {"url": url}, "attrsFormat": "keyValues"}}), headers)
    assert reply.status == 201, reply.body
    reply = http.request("POST", "/v2/entities?options=keyValues",
                         json.dumps({"id": "AGV1", "type": "AGV", "seq": 0}), headers)
    assert reply.status == 201, reply.body
    for seq in range(1, 201):
        reply = http.request("PATCH", "/v2/entities/AGV1/attrs?options=keyValues",
                             json.dumps({"seq": seq}), headers)
        assert reply.status == 204, reply.body
    http.close()
    rig.kill_group(server.child)
    server.child = None

    def restarted() -> ContextBroker:
        cb = ContextBroker(server.folder, port=server.port, token=server.token).start()
        cleanup.append(cb.stop)
        return cb

    again = restarted()
    rec = Receiver(port=port).start()
    cleanup.append(rec.stop)

    def seqs() -> list[int]:
        with rec.lock:
            return [r["body"]["data"][0]["seq"] for r in rec.requests]

    wait_for(lambda: set(range(201)) <= set(seqs()), "all 201 notifications after the restart", 60)
    got = _dedup(seqs())
    assert got == list(range(201)), got[:20]

    port2 = netutil.free_port(HOST)                    # a receiver not listening yet
    http = again.http()
    reply = http.request("GET", "/v2/subscriptions", headers=headers)
    sub_id = reply.json()[0]["id"]
    reply = http.request("PATCH", f"/v2/subscriptions/{sub_id}", json.dumps(
        {"notification": {"http": {"url": f"http://{HOST}:{port2}/notify"}, "attrsFormat": "keyValues"}}),
        headers)
    assert reply.status == 204, reply.body
    for seq in range(201, 211):
        assert http.request("PATCH", "/v2/entities/AGV1/attrs?options=keyValues",
                            json.dumps({"seq": seq}), headers).status == 204
    http.close()
    again.stop()                                       # a clean stop with 10 queued
    rec2 = Receiver(port=port2).start()
    cleanup.append(rec2.stop)
    restarted()
    wait_for(lambda: len(rec2.requests) >= 10, "the 10 queued at the clean stop", 60)
    with rec2.lock:
        later = _dedup([r["body"]["data"][0]["seq"] for r in rec2.requests])
    assert later == list(range(201, 211)), later
