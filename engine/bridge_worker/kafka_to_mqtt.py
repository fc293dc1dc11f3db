"""Kafka -> MQTT: records of the routed Kafka topics are published at QoS 1 on their MQTT topic;
an offset is committed only after the PUBACK of it and of everything before it in its partition.

Everything here runs on the worker's main thread (the MQTT client's callbacks only queue events), so the
ledgers need no lock. Rules that make it lose nothing:

- The consumer group is ``plantkg-bridge-<bridge id>``, auto-commit off. A partition the group
  never committed starts at its end, and that position is committed at once: a record produced
  after the worker became ready is never skipped, even if the worker dies before its first commit.
- Commits are lazy: only offsets PUBACKed at least ``COMMIT_LAG`` s ago over a connection still
  up (Mosquitto keeps messages in memory: what it acknowledged just before a SIGKILL may be gone).
- After an MQTT reconnect every partition is rewound to its committed offset and published again:
  replays give duplicates, never gaps.
- At most ``MAX_UNACKED`` records wait for their PUBACK; past that the half stops consuming and
  waits for PUBACKs (:mod:`engine.bridge_worker.consume_window` says why it does not pause).
- Records carrying this bridge's ``plantkg.bridge`` header (its own MQTT -> Kafka records) are
  skipped, so a topic bridged both ways does not ping-pong.
"""

from __future__ import annotations

import logging
import queue
import time

from confluent_kafka import OFFSET_INVALID, Consumer, KafkaError, KafkaException, Message, TopicPartition

from engine.bridge_worker.config import Direction, Route, WorkerConfig
from engine.bridge_worker.consume_window import ConsumeWindow, Flow
from engine.bridge_worker.health import Health
from engine.bridge_worker.ledgers import PartitionLedger, SentRecord
from engine.bridge_worker.mqtt_link import MqttLink
from engine.bridge_worker.mqtt_to_kafka import BRIDGE_HEADER

log = logging.getLogger("plantkg.bridge.kafka-to-mqtt")

#: Seconds a PUBACK must be old before its offset is committed: Mosquitto may still hold the
#: message in memory, queued for a subscriber that lags; 1 s lost messages in tests on a loaded
#: 2-core machine, so a margin. A larger lag costs only duplicates after a Mosquitto crash.
COMMIT_LAG = 5.0
STOP_COMMIT_LAG = 1.0    # at a clean stop (Mosquitto is up) wait at most this for commits
COMMIT_EVERY = 0.2       # seconds between commit passes
MAX_UNACKED = 5000       # records published and not yet PUBACKed before consuming stops
BATCH = 500              # records taken from the consumer per pass (only those already fetched)
#: A full window reopens at MAX_UNACKED - BATCH unacknowledged, so consuming goes on in batches.
#: Longer full than FULL_PAUSE_AFTER s (its PUBACKs are not coming), the partitions are paused so
#: that the consumer is polled again; a healthy Mosquitto empties the window in ~0.25 s at 20,000
#: msg/s (benchmarks.bench_bridge).
FULL_PAUSE_AFTER = 1.0
ASSIGN_TIMEOUT = 30.0    # seconds to read (and first commit) the positions of new partitions

Partition = tuple[str, int]


def consumer_config(cfg: WorkerConfig, on_error, on_commit) -> dict[str, object]:
    return {
        "bootstrap.servers": cfg.kafka_bootstrap,
        "client.id": cfg.client_id,
        "group.id": cfg.group_id,
        "enable.auto.commit": False,
        "enable.auto.offset.store": False,
        "auto.offset.reset": "latest",
        # How long Kafka may hold a fetch that finds nothing new: a record produced meanwhile
        # waits up to this for a fetch in flight (the default 500 ms, librdkafka's, is latency
        # the bridge adds), while each shorter wait costs an idle worker's Kafka more fetches a
        # second. 10 ms puts that wait under the bridge's 20 ms p99 goal; an instrumented,
        # uncommitted kafka-mqtt run of benchmarks.bench_bridge compared 50, 10 and 5 ms.
        "fetch.wait.max.ms": 10,
        # A worker killed and restarted by its agent rejoins the group: the dead member's
        # partitions are free after this (Kafka's minimum), not after the default 45 s.
        "session.timeout.ms": 6000,
        "heartbeat.interval.ms": 2000,
        "reconnect.backoff.ms": 100,
        "reconnect.backoff.max.ms": 2000,
        "error_cb": on_error,
        "on_commit": on_commit,   # results of the asynchronous commits, served by poll()
        **cfg.kafka_auth(),
    }


class KafkaToMqtt:
    def __init__(self, cfg: WorkerConfig, mqtt_link: MqttLink, health: Health) -> None:
        self.cfg = cfg
        self.health = health
        self.link = mqtt_link
        self.routes: dict[str, Route] = {r.kafka_topic: r for r in cfg.routes_of(Direction.KAFKA_TO_MQTT)}
        self.consumer = Consumer(consumer_config(cfg, self._kafka_error, self._committed))
        self.ledgers: dict[Partition, PartitionLedger] = {}
        self._by_mid: dict[int, SentRecord] = {}
        self._events: queue.SimpleQueue[tuple[str, object]] = queue.SimpleQueue()
        self._connected = False
        self._generation = -1
        self._paused = False
        self._uncounted = 0      # records forwarded since the last health.count (one per pass)
        self._window = ConsumeWindow(MAX_UNACKED, MAX_UNACKED - BATCH, FULL_PAUSE_AFTER)
        self._last_commit = 0.0
        self._own = cfg.bridge_id.encode("utf-8")
        mqtt_link.on_pubacks = lambda mids: self._events.put(("pubacks", mids))
        mqtt_link.on_connection.append(lambda up, gen: self._events.put(("connection", (up, gen))))

    def start(self) -> None:
        self.consumer.subscribe(list(self.routes), on_assign=self._assigned, on_revoke=self._revoked,
                                on_lost=self._revoked)

    @property
    def unacked(self) -> int:
        return len(self._by_mid)

    def step(self, timeout: float) -> None:
        """One turn of the main loop: apply the MQTT client's events, consume records (or wait
        for PUBACKs while the window is full), commit."""
        self._drain_events()
        flow = self._window.decide(self._connected, self.unacked, time.monotonic())
        if flow is Flow.AWAIT_ACKS:
            self._await_event(timeout)
        else:
            self._pause_or_resume(flow is Flow.PAUSE)
            msg = self.consumer.poll(timeout if self._paused else min(timeout, 0.01))
            if msg is not None:
                # poll returns at the first record; what else is already fetched comes without waiting
                room = MAX_UNACKED - self.unacked
                batch = [msg, *self.consumer.consume(min(BATCH, room), 0)] if room > 1 else [msg]
                self._forward(batch)
                self.link.flush()
        self._count_forwarded()
        now = time.monotonic()
        if self._connected and now - self._last_commit >= COMMIT_EVERY:
            self._last_commit = now
            self._commit(now)

    def _count_forwarded(self) -> None:
        """Add what was forwarded to the health counter: once per pass, not per PUBACK (its lock
        showed up in py-spy profiles of the main thread at full speed)."""
        if self._uncounted:
            self.health.count("forwarded_kafka_to_mqtt", self._uncounted)
            self._uncounted = 0

    def _await_event(self, timeout: float) -> None:
        """Wait (at most ``timeout`` s) for the MQTT client's next event, a PUBACK most likely."""
        try:
            kind, value = self._events.get(timeout=timeout)
        except queue.Empty:
            return
        self._apply(kind, value, time.monotonic())
        self._drain_events()

    def _drain_events(self) -> None:
        now = time.monotonic()
        while True:
            try:
                kind, value = self._events.get_nowait()
            except queue.Empty:
                return
            self._apply(kind, value, now)

    def _apply(self, kind: str, value: object, now: float) -> None:
        if kind == "pubacks":
            acked = 0
            for mid in value:  # type: ignore[attr-defined]
                record = self._by_mid.pop(mid, None)
                if record is not None:
                    PartitionLedger.acked(record, now)
                    acked += 1
            self._uncounted += acked
        else:
            self._connected, self._generation = value  # type: ignore[misc]
            self._by_mid.clear()
            if self._connected:
                self._rewind()

    def _pause_or_resume(self, want_pause: bool) -> None:
        if want_pause == self._paused:
            return
        assignment = self._assignment()
        if not assignment:
            return
        (self.consumer.pause if want_pause else self.consumer.resume)(assignment)
        self._paused = want_pause

    def _assignment(self) -> list[TopicPartition]:
        try:
            return self.consumer.assignment()
        except KafkaException:
            return []

    def _forward(self, batch: list[Message]) -> None:
        """Publish a batch of records in one go; the ledgers take them in offset order."""
        entries: list[tuple[PartitionLedger, int, int | None]] = []  # (ledger, offset, QoS or None: skipped)
        messages: list[tuple[str, bytes, int]] = []
        for msg in batch:
            if msg.error():
                if msg.error().code() != KafkaError._PARTITION_EOF:
                    self.health.error(f"Kafka consumer: {msg.error().str()}")
                continue
            ledger = self.ledgers.get((msg.topic(), msg.partition()))
            if ledger is None:  # a record of a partition revoked meanwhile
                continue
            if (BRIDGE_HEADER, self._own) in (msg.headers() or ()):
                entries.append((ledger, msg.offset(), None))
                continue
            route = self.routes[msg.topic()]
            entries.append((ledger, msg.offset(), route.qos))
            messages.append((route.mqtt_topic, msg.value() or b"", route.qos))
        published = self.link.publish_many(self._generation, messages) if messages else []
        if published is None:
            return  # the connection changed: the rewind that follows publishes them again
        mids, now, sent_qos0 = iter(published), time.monotonic(), 0
        for ledger, offset, qos in entries:
            if qos is None:
                ledger.skipped(offset)
                continue
            record, mid = ledger.sent(offset), next(mids)
            if qos == 0:
                PartitionLedger.acked(record, now)
                sent_qos0 += 1
            else:
                self._by_mid[mid] = record
        self._uncounted += sent_qos0

    def _commit(self, now: float, lag: float = COMMIT_LAG, wait: bool = False) -> None:
        """Commit what is due. Asynchronous unless ``wait`` (at a stop): a synchronous commit held
        the main loop 4-20 ms, five times a second, and every record fetched meanwhile waited
        (p99 of the paced run of benchmarks.bench_bridge); the results come to :meth:`_committed`."""
        offsets = []
        for (topic, partition), ledger in self.ledgers.items():
            position = ledger.commit_position(now, lag)
            if position is not None and position > ledger.committed:
                offsets.append(TopicPartition(topic, partition, position))
        if not offsets:
            return
        try:
            done = self.consumer.commit(offsets=offsets, asynchronous=not wait)
        except KafkaException as exc:  # Kafka down: a later pass commits further; replays at worst
            self.health.error(f"Kafka commit failed: {exc}")
            return
        if wait:
            self._note_committed(done or offsets)

    def _committed(self, err: KafkaError | None, partitions: list[TopicPartition]) -> None:
        """on_commit: the result of an asynchronous commit (called from consumer.poll)."""
        if err is not None and err.code() != KafkaError._NO_OFFSET:
            self.health.error(f"Kafka commit failed: {err.str()}")  # a later pass commits further
        self._note_committed(partitions)

    def _note_committed(self, partitions: list[TopicPartition]) -> None:
        for tp in partitions:
            ledger = self.ledgers.get((tp.topic, tp.partition))
            if ledger is not None and tp.error is None and tp.offset >= 0:
                # commits may complete after a rewind: the ledger's commit never goes back
                ledger.committed = max(ledger.committed, tp.offset)

    def _rewind(self) -> None:
        """After an MQTT (re)connect: publish again everything not committed."""
        for (topic, partition), ledger in self.ledgers.items():
            position = ledger.rewind()
            try:
                self.consumer.seek(TopicPartition(topic, partition, position))
            except KafkaException as exc:
                self.health.error(f"Kafka seek {topic}[{partition}] to {position} failed: {exc}")
        if self.ledgers:
            log.info("rewound %d partitions to their committed offsets", len(self.ledgers))

    # rebalance callbacks (called from consumer.poll on the main thread)
    def _assigned(self, consumer: Consumer, partitions: list[TopicPartition]) -> None:
        positions = self._starting_positions(partitions)
        for tp in positions:
            self.ledgers[(tp.topic, tp.partition)] = PartitionLedger(committed=tp.offset)
        consumer.assign(positions)
        if self._paused or not self._connected:
            consumer.pause(positions)
            self._paused = True
        log.info("assigned %s", ", ".join(f"{t.topic}[{t.partition}]@{t.offset}" for t in positions))
        self.health.set(assigned=True)

    def _starting_positions(self, partitions: list[TopicPartition]) -> list[TopicPartition]:
        """Committed offsets; for a partition never committed, its end, committed now."""
        deadline = time.monotonic() + ASSIGN_TIMEOUT
        while True:
            try:
                known = self.consumer.committed(partitions, timeout=5)
                fresh = [TopicPartition(tp.topic, tp.partition,
                                        self.consumer.get_watermark_offsets(tp, timeout=5)[1])
                         for tp in known if tp.offset == OFFSET_INVALID]
                if fresh:
                    self.consumer.commit(offsets=fresh, asynchronous=False)
                ends = {(tp.topic, tp.partition): tp.offset for tp in fresh}
                return [TopicPartition(tp.topic, tp.partition, ends.get((tp.topic, tp.partition), tp.offset))
                        for tp in known]
            except KafkaException as exc:
                if time.monotonic() > deadline:
                    raise
                self.health.error(f"Kafka: reading committed offsets failed: {exc}; retrying")

    def _revoked(self, _consumer: Consumer, partitions: list[TopicPartition]) -> None:
        for tp in partitions:
            self.ledgers.pop((tp.topic, tp.partition), None)
        self._by_mid.clear()  # PUBACKs still due only delay commits that a new owner redoes
        if not self.ledgers:
            self.health.set(assigned=False)

    def _kafka_error(self, err: KafkaError) -> None:
        self.health.error(f"Kafka consumer ({self.cfg.kafka_bootstrap}): {err.str()}")

    def stop(self, deadline: float) -> None:
        """Stop consuming; wait (until the monotonic ``deadline``) for the PUBACKs in flight and
        their commit lag; commit; leave the group."""
        assignment = self._assignment()
        if assignment:
            self.consumer.pause(assignment)
        self._paused = True
        while time.monotonic() < deadline and self._connected and any(l.records for l in self.ledgers.values()):
            self._drain_events()
            self._commit(time.monotonic(), STOP_COMMIT_LAG, wait=True)
            time.sleep(0.05)  # bounded by the deadline; PUBACKs arrive on the MQTT client's thread
        self._count_forwarded()
        self.consumer.close()
