"""MQTT notifications (paho-mqtt 2.x): the notification JSON published on ``topic``.

One persistent client per broker and credentials (``url``, ``user``, ``passwd``), created at its
first notification (``mqtts://``: TLS, verified against the plant CA's ``ca.pem``); paho's
network thread reconnects it (0.5 s doubling to 30 s). A publish counts as sent when the broker
acknowledged it: for QoS 1 and 2 the PUBACK/PUBCOMP must arrive within :data:`ACK_TIMEOUT`, for
QoS 0 the message must have been handed to a connected client. A client that is not connected is
a temporary failure (the lane retries). Up to the lane's window of notifications are published
back to back before their acknowledgements are awaited (``send_many``), so a subscription's rate
is not one broker round trip per notification. Delivery is at least once: a QoS 1 message whose
PUBACK was late, or that followed one, may arrive twice.
"""

from __future__ import annotations

import ssl
import threading
import time
import uuid

from paho.mqtt import client as paho
from paho.mqtt.enums import CallbackAPIVersion

from engine.context_broker.subscriptions.model import MqttTarget
from engine.context_broker.subscriptions.render import Outgoing
from engine.context_broker.subscriptions.result import Result
from engine.security import ca

CONNECT_WAIT = 5.0
ACK_TIMEOUT = 10.0
KEEPALIVE = 30


class MqttSender:
    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._clients: dict[tuple[str, int, str | None, str | None, bool], paho.Client] = {}

    def _client(self, target: MqttTarget) -> paho.Client:
        """The client of ``target``'s broker and login; raises OSError, ssl.SSLError or CaError
        when the plant CA's certificate cannot be read for an ``mqtts://`` target."""
        key = (target.host, target.port, target.user, target.passwd, target.tls)
        with self._lock:
            client = self._clients.get(key)
            if client is None:
                client = paho.Client(CallbackAPIVersion.VERSION2,
                                     client_id=f"plantkg-cb-{uuid.uuid4().hex[:12]}")
                if target.user is not None:
                    client.username_pw_set(target.user, target.passwd)
                if target.tls:  # verified against the plant CA only, with the broker's address
                    client.tls_set(ca_certs=str(ca.ca_cert_file()))
                client.reconnect_delay_set(0.5, 30)
                client.user_data_set({"last": "no answer yet"})
                client.on_connect = _remember
                client.on_disconnect = _remember_disconnect
                client.on_connect_fail = _remember_fail
                client.connect_async(target.host, target.port, keepalive=KEEPALIVE)
                client.loop_start()
                self._clients[key] = client
            return client

    def send(self, target: MqttTarget, msg: Outgoing) -> Result:
        return self.send_many(target, [msg])[0]

    def send_many(self, target: MqttTarget, msgs: list[Outgoing]) -> list[Result]:
        """Publish ``msgs`` back to back, then wait for their acknowledgements in order: one
        result per message up to and including the first failure (paho keeps the order on its
        one connection, so pipelining changes nothing the receiver sees)."""
        try:
            client = self._client(target)
        except (OSError, ssl.SSLError, ca.CaError) as err:  # the plant CA for mqtts://
            return [Result.temporary(f"MQTT broker {target.host}:{target.port}: cannot set up TLS "
                                     f"with the plant CA ({err})")]
        deadline = time.monotonic() + CONNECT_WAIT
        while not client.is_connected():
            if time.monotonic() >= deadline:
                last = (client.user_data_get() or {}).get("last", "")
                return [Result.temporary(f"MQTT broker {target.host}:{target.port} not connected "
                                         f"({last})")]
            time.sleep(0.02)  # polling paho's connection flag, bounded by the deadline above
        published: list[paho.MQTTMessageInfo] = []
        refused: Result | None = None
        for msg in msgs:
            try:
                info = client.publish(target.topic, msg.body, qos=target.qos, retain=target.retain)
            except (ValueError, OSError) as err:
                refused = Result.temporary(f"MQTT publish failed: {err}")
                break
            if info.rc != paho.MQTT_ERR_SUCCESS:
                refused = Result.temporary(f"MQTT publish failed: {paho.error_string(info.rc)}")
                break
            published.append(info)
        results: list[Result] = []
        for info in published:
            result = self._acknowledged(target, info)
            results.append(result)
            if not result.ok:
                return results
        if refused is not None:
            results.append(refused)
        return results

    @staticmethod
    def _acknowledged(target: MqttTarget, info: paho.MQTTMessageInfo) -> Result:
        if target.qos == 0:
            return Result.success()
        try:
            info.wait_for_publish(timeout=ACK_TIMEOUT)
        except (RuntimeError, ValueError) as err:
            return Result.temporary(f"MQTT publish failed: {err}")
        if not info.is_published():
            return Result.temporary(f"no PUBACK from {target.host}:{target.port} within "
                                    f"{ACK_TIMEOUT:g} s")
        return Result.success()

    def close(self) -> None:
        with self._lock:
            clients, self._clients = list(self._clients.values()), {}
        for client in clients:
            client.disconnect()
            client.loop_stop()


def _remember(_client: paho.Client, userdata: dict, _flags: object, reason: object, _props: object) -> None:
    userdata["last"] = f"CONNACK: {reason}"


def _remember_disconnect(_client: paho.Client, userdata: dict, _flags: object, reason: object,
                         _props: object) -> None:
    userdata["last"] = f"disconnected: {reason}"


def _remember_fail(_client: paho.Client, userdata: dict) -> None:
    userdata["last"] = "connection refused or unreachable"
