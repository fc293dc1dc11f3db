"""Simulated data on a context broker, for the demo: a resource writing its entity, and a tap.

A resource that publishes a topic on a context broker (the task planner of the AGV example writing
motion and action commands) writes the topic's entity there: one
``POST /v2/entities?options=upsert&options=keyValues`` per message, with its agent's token, at
1 Hz. An :class:`NgsiTap` reads every entity of its broker's topics (``GET /v2/entities/<id>``,
``keyValues``, with its agent's token) twice a second and counts the changes it sees, so the demo shows the attribute
values that really are on the context broker, whether a source wrote them or the MQTT <-> NGSI
bridge did. Plain ``http.client`` (no proxy: the broker is addressed directly), HTTPS trusting the
plant CA for a ``pk:tls`` broker.
"""

from __future__ import annotations

import json
import threading
import time
import urllib.parse
from typing import Any

from engine.model import BrokerSpec
from engine.security import https
from engine.demo.simulate import Feed, Seen, payload

#: How often an NGSI source writes, and how often a tap reads.
RATE_HZ = 1.0
POLL_S = 0.5
#: Attributes the tap leaves out of the last values it shows (bookkeeping, not data).
HIDDEN = frozenset({"id", "type", "ts", "source", "TimeInstant", "dateCreated", "dateModified"})


def _request(broker: BrokerSpec, method: str, path: str, body: Any = None, token: str | None = None,
             timeout: float = 5.0) -> tuple[int, bytes]:
    conn = https.connection(broker.host, broker.port, timeout=timeout, tls=broker.tls)  # pk:tls: the plant CA
    try:
        headers = {"Accept": "application/json"}
        data = None
        if body is not None:
            data = json.dumps(body).encode()
            headers["Content-Type"] = "application/json"
        if token:
            headers["Authorization"] = f"Bearer {token}"
        conn.request(method, path, body=data, headers=headers)
        answer = conn.getresponse()
        return answer.status, answer.read()
    finally:
        conn.close()


def entity_path(entity_id: str, entity_type: str) -> str:
    """``/v2/entities/<id>?type=<type>&options=keyValues`` with the id percent-encoded."""
    query = urllib.parse.urlencode({"type": entity_type, "options": "keyValues"})
    return f"/v2/entities/{urllib.parse.quote(entity_id, safe='')}?{query}"


class NgsiSource(threading.Thread):
    """Writes ``feed``'s entity on its context broker at :data:`RATE_HZ` until stopped."""

    def __init__(self, feed: Feed, entity_id: str, entity_type: str, token: str | None,
                 stop: threading.Event) -> None:
        super().__init__(name=f"ngsi-source-{feed.resource}", daemon=True)
        self.feed, self.entity_id, self.entity_type = feed, entity_id, entity_type
        self.token, self.stop_event = token, stop
        self.sent = 0
        self.errors: list[str] = []

    def run(self) -> None:
        start = time.monotonic()
        while not self.stop_event.is_set():
            body = json.loads(payload(self.feed, self.sent, time.monotonic() - start))
            entity = {"id": self.entity_id, "type": self.entity_type, **body}
            try:
                status, text = _request(self.feed.broker, "POST", "/v2/entities?options=upsert,keyValues",
                                        entity, self.token)
            except OSError as exc:
                status, text = 0, str(exc).encode()
            if status in (200, 201, 204):
                self.sent += 1
            elif len(self.errors) < 5:
                self.errors.append(f"{status}: {text[:200].decode('utf-8', 'replace')}")
            self.stop_event.wait(1.0 / RATE_HZ)


class NgsiTap(threading.Thread):
    """Reads the entities of ``topics`` (topic name -> (entity id, entity type)) on ``broker``."""

    def __init__(self, broker: BrokerSpec, topics: dict[str, tuple[str, str]], stop: threading.Event,
                 token: str | None = None) -> None:
        """``token``: its agent's, for a closed context broker (reads need it too)."""
        super().__init__(name=f"ngsi-tap-{broker.id}", daemon=True)
        self.broker, self.topics, self.stop_event, self.token = broker, topics, stop, token
        self.seen: dict[str, Seen] = {t: Seen() for t in topics}
        self.ready = threading.Event()
        self._previous: dict[str, bytes] = {}
        self._lock = threading.Lock()

    def run(self) -> None:
        while True:
            for topic, (entity_id, entity_type) in self.topics.items():
                self._read(topic, entity_id, entity_type)
            self.ready.set()
            if self.stop_event.wait(POLL_S):
                return

    def _read(self, topic: str, entity_id: str, entity_type: str) -> None:
        try:
            status, body = _request(self.broker, "GET", entity_path(entity_id, entity_type), token=self.token)
        except OSError:
            return
        if status != 200 or body == self._previous.get(topic):
            return
        self._previous[topic] = body
        try:
            values = json.loads(body)
        except ValueError:
            return
        with self._lock:
            entry = self.seen[topic]
            entry.count += 1
            entry.last = {k: v for k, v in values.items() if k not in HIDDEN}

    def snapshot(self) -> dict[str, Seen]:
        with self._lock:
            return {t: Seen(s.count, dict(s.last)) for t, s in self.seen.items()}
