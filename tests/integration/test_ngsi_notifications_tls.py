"""The context broker's MQTT notifications at a closed, TLS-only Mosquitto (issue 13), end to end.

``plantkg apply`` of a plant file, real agents (127.0.0.2: Mosquitto with ``pk:tls true``, closed
by default; 127.0.0.3: the context broker). The planner is a principal of the context broker (its
token in a file); the AGV a user of Mosquitto (its password in the agents' environment). Rule R1
derives the MQTT <-> NGSI bridge; its worker subscribes the order entity with an ``mqtts://`` url
and the notify principal's login. Checked: the notify principal may write exactly the topic the
bridge brings back, the subscription says ``mqtts://``, and an order the planner writes with its
token reaches the AGV over TLS, published by the context broker logged in as that principal.
"""

from __future__ import annotations

import json
import secrets
import threading
import uuid
from collections.abc import Iterator
from dataclasses import dataclass

import pytest
import requests
from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import process
from engine.security import ca
from tests.integration.agents import Deployment, deployment, secret_files

pytestmark = pytest.mark.integration

MQ_HOST, CB_HOST = "127.0.0.2", "127.0.0.3"
ORDER_ID, ORDER_TOPIC = "urn:ngsi-ld:Order:agv1", "agv/1/order"
AGV_ENV = "PLANTKG_TEST_NOTIFY_AGV_PW"

PLANT = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <https://example.org/notify-tls#> .
:mq a pk:Broker ; pk:id "mq" ; pk:name "mq" ; pk:brokerType "mosquitto" ; pk:ip "{mq_host}" ;
    pk:port {mq_port} ; pk:tls true ; pk:hasTopic :status , :order .
:cb a pk:Broker ; pk:id "cb" ; pk:name "cb" ; pk:brokerType "ngsi-v2" ; pk:ip "{cb_host}" ; pk:port {cb_port} ;
    pk:hasTopic :status , :order .
:status a pk:Topic ; pk:id "status" ; pk:name "agv/1/status" ; pk:qos 1 .
:order a pk:Topic ; pk:id "order" ; pk:name "{order_topic}" ; pk:qos 1 ; pk:entityId "{order_id}" ;
    pk:entityType "Order" .
:agv a pk:Resource ; pk:id "agv" ; pk:name "agv" ; pk:sendsTo :mq ; pk:publishes :status ;
    pk:subscribes :order ; pk:secretRef "env:{agv_env}" .
:planner a pk:Resource ; pk:id "planner" ; pk:name "planner" ; pk:sendsTo :cb ; pk:subscribes :status ;
    pk:publishes :order ; pk:secretRef "file:{planner_file}" .
"""


@dataclass(frozen=True)
class Plant:
    deployed: Deployment
    agv_password: str
    planner_token: str


@pytest.fixture(scope="module")
def plant(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Plant]:
    tmp = tmp_path_factory.mktemp("notify-tls")
    agv_password, planner_token = secrets.token_urlsafe(16), secrets.token_urlsafe(16)
    planner_file = secret_files(tmp / "secrets", {"planner": planner_token}) / "planner"

    def render(ports: dict[str, int]) -> str:
        return PLANT.format(mq_host=MQ_HOST, cb_host=CB_HOST, mq_port=ports["mq"], cb_port=ports["cb"],
                            order_topic=ORDER_TOPIC, order_id=ORDER_ID, agv_env=AGV_ENV, planner_file=planner_file)

    with deployment(tmp, {"mq": MQ_HOST, "cb": CB_HOST}, render, agent_env={AGV_ENV: agv_password}) as made:
        yield Plant(made, agv_password, planner_token)


def test_the_notify_principal_writes_exactly_the_topic_brought_back(plant: Plant) -> None:
    users = {u.name: u for u in plant.deployed.fleet.brokers()["mq"].spec.users}
    notify = users["plantkg.notify.mq.cb"]
    assert (notify.write, notify.read) == ((ORDER_TOPIC,), ())
    worker = users["plantkg.bridge.mq.cb"]
    assert (worker.write, worker.read) == ((), ("agv/1/status",))


def test_an_order_reaches_the_agv_over_tls_at_the_closed_broker(plant: Plant) -> None:
    got: list[dict] = []
    subscribed = threading.Event()
    agv = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"it-agv-{uuid.uuid4().hex[:8]}")
    agv.tls_set(ca_certs=str(ca.ca_cert_file()))
    agv.username_pw_set("agv", plant.agv_password)
    agv.on_connect = lambda c, _u, _f, reason, _p: c.subscribe(ORDER_TOPIC, qos=1)
    agv.on_subscribe = lambda *_: subscribed.set()
    agv.on_message = lambda _c, _u, msg: got.append(json.loads(msg.payload))
    agv.connect(MQ_HOST, plant.deployed.ports["mq"], keepalive=10)
    agv.loop_start()
    cb = f"http://{CB_HOST}:{plant.deployed.ports['cb']}"
    planner = {"Authorization": f"Bearer {plant.planner_token}"}
    try:
        process.wait_until(subscribed.is_set, 30.0, what="the AGV's subscription over TLS")

        def mqtts_subscription() -> bool:
            answer = requests.get(f"{cb}/v2/subscriptions", timeout=10,
                                  headers={"Authorization": f"Bearer {plant.deployed.fleet.agents[CB_HOST].token}"})
            subs = answer.json() if answer.status_code == 200 else []
            return any(s["notification"]["mqtt"]["url"] == f"mqtts://{MQ_HOST}:{plant.deployed.ports['mq']}"
                       and s["notification"]["mqtt"].get("user") == "plantkg.notify.mq.cb" for s in subs)
        process.wait_until(mqtts_subscription, 60.0, what="the worker's mqtts:// subscription")
        seq = 0

        def order_arrived() -> bool:
            nonlocal seq
            seq += 1
            answer = requests.post(f"{cb}/v2/entities?options=upsert,keyValues", timeout=10, headers=planner,
                                   json={"id": ORDER_ID, "type": "Order", "seq": seq})
            assert answer.status_code in (201, 204), answer.text
            return bool(got)  # the entity did not exist before: any message is one of these orders
        process.wait_until(order_arrived, 60.0, what="an order notified to the AGV", interval=1.0)
        data = [d for m in got for d in m.get("data", [])]
        assert data and all(d["id"] == ORDER_ID and 1 <= d["seq"] <= seq for d in data), got
    finally:
        agv.loop_stop()
        agv.disconnect()
