"""MQTT -> Kafka: every message of a subscribed topic becomes one Kafka record; the MQTT message
is acknowledged only after Kafka confirmed the write.

The producer is idempotent with ``acks=all`` and no delivery timeout: librdkafka retries a write
that did not go through (Kafka down, a leader moving) itself, in order, for as long as it takes.
A delivery that fails anyway (a permanent error: topic missing, not authorised), or a produce call
that librdkafka refuses at once (a topic it knows to be missing: ``_UNKNOWN_TOPIC``), is produced
again after a short backoff and counted in ``retried``; its MQTT message stays unacknowledged
meanwhile. While a topic has records waiting for a retry, its new records queue behind them, so
the topic's order holds (other topics go on).

A missing topic is expected for a while: plantkg's Kafka does not create topics on demand
(``auto.create.topics.enable=false``, issue 13), and apply runs the bridge in its Mosquitto's lane,
in parallel with the Kafka lane that creates the topic. librdkafka reports the topic missing after
``topic.metadata.propagation.max.ms`` (30 s); the records are then retried until it exists.

The record: value = the payload untouched; key = the MQTT topic (all of a topic's messages in one
partition, in order) or none; headers ``mqtt.topic``, ``mqtt.qos``, ``mqtt.received_at`` (ms since
the epoch) and ``plantkg.bridge`` (the bridge id, so the Kafka -> MQTT half skips its own
records); the record timestamp is the receive time.
"""

from __future__ import annotations

import heapq
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from confluent_kafka import KafkaError, KafkaException, Message, Producer

from engine.bridge_worker.config import Direction, KeyMode, Route, WorkerConfig
from engine.bridge_worker.health import Health
from engine.bridge_worker.ledgers import InOrderAcks, PendingAck
from engine.bridge_worker.mqtt_link import MqttLink
from engine.bridge_worker.mqtt_wire import Publish

log = logging.getLogger("plantkg.bridge.mqtt-to-kafka")

RETRY_BACKOFF = 1.0   # seconds before a failed delivery is produced again
#: Messages received and not yet confirmed by Kafka the worker takes at once (its MQTT Receive
#: Maximum; it stops reading there). A message's PUBACK waits for Kafka's answer, so this window
#: must cover the rate times Kafka's answer time, or reading stops and messages wait in Mosquitto.
#: On two shared cores Kafka's acks=all answers take from milliseconds to a few hundred at the
#: tail: at 20,000 msg/s a window of 1000 is 50 ms of traffic and kept filling in instrumented,
#: uncommitted bench_bridge runs, which 5000 (as KafkaToMqtt's MAX_UNACKED) did not; the committed
#: mqtt-kafka rows with 5000 sustain over 20,000 msg/s (benchmarks/results/bridge.md).
#: A SIGKILLed worker's duplicates grow with it (at most about twice this).
IN_FLIGHT = 5000
#: Seconds the MQTT I/O thread waits at most for its socket while Kafka writes are outstanding
#: before it serves delivery reports again: a written message's PUBACK waits at most this long on
#: top of Kafka's answer (2 ms = 20 messages at 10,000 msg/s, under 1% of IN_FLIGHT; not tuned
#: further: the worker's wake-ups with messages arriving every 0.1 ms outnumber these).
PUMP_EVERY = 0.002
#: Seconds after which the fallback thread serves delivery reports itself when the I/O thread has
#: not (it is reconnecting, or blocked writing to a slow broker): the poll timeout of the
#: producer thread before issue 16.
FALLBACK_AFTER = 0.05
IDLE_WAIT = 0.5       # seconds the I/O thread may wait when no Kafka write is outstanding
BRIDGE_HEADER = "plantkg.bridge"


#: librdkafka's ``linger.ms``: how long a record waits for others to share its produce request.
#: 5 ms rather than 2 (before issue 16): fewer, larger requests, so less CPU per message in
#: librdkafka's broker thread and in Kafka, for a few ms more at p50; alternating paced runs of
#: bench_bridge (instrumented, not committed) favoured 5 ms at the tail on two shared cores.
LINGER_MS = 5


def producer_config(cfg: WorkerConfig, on_error: Callable[[KafkaError], None]) -> dict[str, object]:
    return {
        "bootstrap.servers": cfg.kafka_bootstrap,
        "client.id": cfg.client_id,
        "enable.idempotence": True,
        "acks": "all",
        "message.timeout.ms": 0,          # never give up: librdkafka retries in order
        "linger.ms": LINGER_MS,
        "reconnect.backoff.ms": 100,
        "reconnect.backoff.max.ms": 2000,
        "error_cb": on_error,
        **cfg.kafka_auth(),
    }


class _Record:
    """One Kafka record to write, and the MQTT message it acknowledges once written."""

    __slots__ = ("topic", "value", "key", "headers", "timestamp", "entry", "half")

    def __init__(self, topic: str, value: bytes, key: bytes | None, headers: list[tuple[str, bytes]],
                 timestamp: int, entry: PendingAck | None, half: MqttToKafka) -> None:
        self.topic, self.value, self.key, self.headers = topic, value, key, headers
        self.timestamp, self.entry, self.half = timestamp, entry, half

    def delivered(self, err: KafkaError | None, _msg: Message) -> None:
        self.half._delivered(self, err)


@dataclass(order=True)
class _Retry:
    due: float
    seq: int
    record: _Record = field(compare=False)


class MqttToKafka:
    """Subscribed MQTT messages -> Kafka records. Messages arrive on the MQTT client's I/O
    thread, and the same thread serves Kafka's delivery reports (:meth:`_pump`) and writes the
    PUBACKs they release.

    Why one thread: confluent-kafka takes the GIL once per delivery report. Served on a thread of
    their own (a blocking ``poll`` loop, as before issue 16), 10,000 reports a second meant as
    many hand-overs of the GIL between two threads, each a wake-up that waits for the other thread
    to be scheduled, and PUBACKs that waited for a third wake-up of the I/O thread. On one thread
    the worker switches context about half as often per message (instrumented, uncommitted
    bench_bridge runs; the committed CPU per message is in benchmarks/results/bridge.md). A
    fallback thread serves the reports only while the I/O thread does not (reconnecting, or
    blocked writing)."""

    def __init__(self, cfg: WorkerConfig, mqtt_link: MqttLink, health: Health) -> None:
        self.cfg = cfg
        self.health = health
        self.routes: dict[str, Route] = {r.mqtt_topic: r for r in cfg.routes_of(Direction.MQTT_TO_KAFKA)}
        self.link = mqtt_link
        self.acks = InOrderAcks(mqtt_link.ack_later)   # written by the I/O thread's next pass
        self.producer = Producer(producer_config(cfg, self._kafka_error))
        self._stopping = threading.Event()
        self._done = threading.Event()
        self._retries: list[_Retry] = []
        self._parked: dict[str, tuple[int, float]] = {}  # topic -> (records in _retries, last due)
        self._retry_lock = threading.Lock()
        self._seq = 0
        self._written = 0   # records confirmed since the last _serve (guarded by _serving)
        self._serving = threading.RLock()   # one thread at a time serves delivery reports
        self._last_pump = 0.0               # monotonic time of the I/O thread's last _pump
        self._own = cfg.bridge_id.encode("utf-8")
        self._thread = threading.Thread(target=self._fallback_loop, name="kafka-producer", daemon=True)
        mqtt_link.on_message = self.on_message
        mqtt_link.pump_on_io_thread(self._pump)
        mqtt_link.on_connection.append(self._connection_changed)
        mqtt_link.hold_reading_while(lambda: len(self.acks) >= mqtt_link.receive_maximum)

    def start(self) -> None:
        self._thread.start()

    def on_message(self, msg: Publish) -> None:
        """The MQTT client's thread: one PUBLISH received."""
        if self._stopping.is_set():
            return  # not acknowledged: the broker sends it again to the next worker session
        route = self.routes.get(msg.topic)
        if route is None:  # a subscription left in the session by an earlier configuration
            log.warning("dropping a message on %r: no route (unsubscribing)", msg.topic)
            self.link.unsubscribe(msg.topic)
            self.link.ack(msg.mid, msg.qos)
            return
        entry = self.acks.add(msg.mid, msg.qos) if msg.qos > 0 else None
        received_ms = int(time.time() * 1000)
        topic = msg.topic.encode("utf-8")
        headers = [("mqtt.topic", topic), ("mqtt.qos", b"1" if msg.qos else b"0"),
                   ("mqtt.received_at", str(received_ms).encode()), (BRIDGE_HEADER, self._own)]
        self._send(_Record(route.kafka_topic, msg.payload, topic if route.key is KeyMode.MQTT_TOPIC else None,
                           headers, received_ms, entry, self))

    def _send(self, record: _Record) -> None:
        """Produce, unless older records of the topic wait for a retry: then queue behind them."""
        if self._parked:  # only then is the lock needed: _parked is empty on the fast path
            with self._retry_lock:
                parked = self._parked.get(record.topic)
                if parked is not None:
                    self._park(record, parked[1])
                    return
        self._produce(record)

    def _produce(self, record: _Record) -> None:
        while True:
            try:
                self.producer.produce(record.topic, value=record.value, key=record.key,
                                      headers=record.headers, timestamp=record.timestamp,
                                      on_delivery=record.delivered)
                return
            except BufferError:  # librdkafka's queue is full: let deliveries drain it
                with self._serving:
                    self.producer.poll(0.05)
            except KafkaException as exc:  # e.g. _UNKNOWN_TOPIC: the topic does not exist (yet)
                self._retry_later(record, exc.args[0].str() if exc.args else str(exc))
                return

    def _retry_later(self, record: _Record, why: str) -> None:
        self.health.count("retried")
        self.health.error(f"Kafka delivery to {record.topic!r} failed: {why}; retrying")
        with self._retry_lock:
            self._park(record, time.monotonic() + RETRY_BACKOFF)

    def _park(self, record: _Record, due: float) -> None:
        """Queue ``record`` for a produce at ``due`` (the caller holds the retry lock)."""
        count, last = self._parked.get(record.topic, (0, due))
        due = max(due, last)  # never before an older record of the same topic
        self._parked[record.topic] = (count + 1, due)
        self._seq += 1
        heapq.heappush(self._retries, _Retry(due, self._seq, record))

    def _delivered(self, record: _Record, err: KafkaError | None) -> None:
        """Kafka's answer about one record (the thread serving reports holds ``_serving``)."""
        if err is None:
            self._written += 1
            if record.entry is not None:
                self.acks.confirm(record.entry)
            return
        self._retry_later(record, err.str())

    def _pump(self) -> float:
        """The MQTT I/O thread, on each pass: serve the delivery reports that came (the PUBACKs
        they release leave on this pass's write); how long the thread may then wait."""
        self._last_pump = time.monotonic()
        self._serve()
        return PUMP_EVERY if len(self.producer) or self._retries else IDLE_WAIT

    def _fallback_loop(self) -> None:
        """Serve delivery reports while the I/O thread does not, and wake it for their PUBACKs."""
        while not self._done.wait(FALLBACK_AFTER):
            if time.monotonic() - self._last_pump >= FALLBACK_AFTER:
                self._serve()
                self.link.flush()

    def _serve(self) -> None:
        """Serve the delivery reports that came, without waiting; add the records written to the
        counter; produce again the retries now due. Skipped while another thread serves."""
        if not self._serving.acquire(blocking=False):
            return
        try:
            self.producer.poll(0)
            self._count_written()
            if self._retries:
                self._resend_due()
        finally:
            self._serving.release()

    def _count_written(self) -> None:
        """Add the records written since the last call to the counter (holding ``_serving``)."""
        if self._written:
            self.health.count("forwarded_mqtt_to_kafka", self._written)
            self._written = 0

    def _resend_due(self) -> None:
        now = time.monotonic()
        due = []
        with self._retry_lock:
            while self._retries and self._retries[0].due <= now:
                record = heapq.heappop(self._retries).record
                count, last = self._parked[record.topic]
                if count > 1:
                    self._parked[record.topic] = (count - 1, last)
                else:
                    del self._parked[record.topic]
                due.append(record)
        for record in due:  # in order; one that fails again parks the rest of its topic behind it
            self._send(record)

    def _connection_changed(self, up: bool, _generation: int) -> None:
        if not up:
            dropped = self.acks.connection_lost()
            if dropped:
                log.info("%d messages unacknowledged at disconnect; the broker will send them again", dropped)

    def _kafka_error(self, err: KafkaError) -> None:
        # librdkafka's own texts ("1/1 brokers are down") do not always name the address: add it,
        # so the operator reading the worker's status knows which Kafka to look at
        self.health.error(f"Kafka producer ({self.cfg.kafka_bootstrap}): {err.str()}")

    def stop(self, deadline: float) -> None:
        """Take no new message; wait (until the monotonic ``deadline``) for the writes in flight
        and their PUBACKs; then stop the fallback thread."""
        self._stopping.set()
        while len(self.acks) and time.monotonic() < deadline:
            with self._serving:
                self.producer.flush(min(0.2, max(0.0, deadline - time.monotonic())))
                self._count_written()
            self.link.flush()
        if len(self.acks):
            log.warning("%d messages still unconfirmed at stop: the broker sends them again", len(self.acks))
        self._done.set()
        self._thread.join(timeout=5)
