"""The dashboard's live message rates: messages per second per (broker, topic), the last minute.

For every topic the plant's desired state puts on a Mosquitto or Kafka broker that an agent reports
running, a tap of :mod:`engine.check.watch` subscribes (MQTT without retained messages, Kafka from
the partitions' current end) and each message adds one to a :class:`RateRing` of its (broker,
topic): one-second buckets, the last ``window`` seconds, so memory is bounded by the topics watched
(at most :data:`MAX_WATCHED`, the rows the dashboard shows) whatever the traffic.

:class:`RateMonitor` follows the plant: once a second it compares the targets (broker, address,
topics, and the broker process's pid — a restarted broker gets a new tap, since an MQTT client's
subscriptions do not survive it) with the taps it runs, starts what is new and stops what went.
Each tap runs in a thread of its own that connects with a timeout and retries with a backoff, so
an unreachable or slow broker never holds up the others; an MQTT tap whose client reconnected by
itself (its subscriptions lost with the old session) is renewed. :meth:`RateMonitor.stop` stops and joins
every thread it started. Probes of ``plantkg check`` are real messages on the topic: counted too.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from engine.check.flows import WATCHABLE_KINDS
from engine.check.watch import Endpoint, KafkaTap, MqttTap, Tap
from engine.model import BrokerStatus, DesiredState, ObservedState
from engine.security import kafka_client

log = logging.getLogger(__name__)

WINDOW_S = 60
#: At most this many (broker, topic) pairs are watched: the dashboard shows the first 500 topic rows.
MAX_WATCHED = 500
CONNECT_TIMEOUT = 5.0   # seconds a tap has to connect and subscribe before it is retried
MAX_BACKOFF = 10.0      # seconds between two tries at an unreachable broker, at most


class RateRing:
    """Counts per second for the last ``window`` seconds (pure; not thread-safe on its own).

    Seconds are whole numbers of any clock; a bucket is reused once its second left the window.
    """

    def __init__(self, window: int = WINDOW_S) -> None:
        if window < 1:
            raise ValueError(f"window must be at least 1 second, not {window}")
        self.window = window
        self.total = 0
        self._counts = [0] * window
        self._seconds = [-1] * window   # which second each bucket holds now

    def add(self, second: int, n: int = 1) -> None:
        """Count ``n`` messages in ``second`` (a late second already out of the window is dropped
        from the buckets, but still counts in ``total``)."""
        self.total += n
        slot = second % self.window
        if self._seconds[slot] != second:
            if self._seconds[slot] > second:
                return  # older than what the bucket holds: out of the window
            self._seconds[slot], self._counts[slot] = second, 0
        self._counts[slot] += n

    def series(self, last: int) -> list[int]:
        """Messages in each second from ``last - window + 1`` to ``last``, oldest first."""
        out = []
        for second in range(last - self.window + 1, last + 1):
            slot = second % self.window
            out.append(self._counts[slot] if self._seconds[slot] == second else 0)
        return out


@dataclass(frozen=True)
class RateTarget:
    """One tap to run: a broker, the topics to count there, and the broker process it is for."""

    endpoint: Endpoint
    topics: tuple[str, ...]
    pid: int | None


def rate_targets(desired: DesiredState | None, observed: ObservedState | None,
                 limit: int = MAX_WATCHED) -> tuple[RateTarget, ...]:
    """The taps the plant asks for: each running Mosquitto/Kafka broker of the desired state with
    its desired topics, in the desired state's order, at most ``limit`` topics in all (pure)."""
    if desired is None or observed is None:
        return ()
    left = limit
    by_broker: dict[str, list[str]] = {}
    for topic in desired.topics:
        if left <= 0:
            break
        spec = desired.broker(topic.broker_id)
        have = observed.broker(topic.broker_id)
        if spec is None or spec.kind not in WATCHABLE_KINDS or have is None or have.status is not BrokerStatus.RUNNING:
            continue
        by_broker.setdefault(spec.id, []).append(topic.name)
        left -= 1
    targets = []
    for broker_id, topics in by_broker.items():
        spec, have = desired.broker(broker_id), observed.broker(broker_id)
        assert spec is not None and have is not None
        targets.append(RateTarget(Endpoint(spec.id, spec.kind, spec.host, spec.port, spec.tls,
                                           kafka_client.is_closed(spec)),
                                  tuple(sorted(set(topics))), have.pid))
    return tuple(sorted(targets, key=lambda t: t.endpoint.broker))


class RateBook:
    """The rings of the watched (broker, topic) pairs (thread-safe); other topics are not kept."""

    def __init__(self, window: int = WINDOW_S, clock: Callable[[], float] = time.monotonic) -> None:
        self.window = window
        self._clock = clock
        self._lock = threading.Lock()
        self._rings: dict[tuple[str, str], RateRing] = {}

    def count(self, broker: str, topic: str, n: int = 1) -> None:
        second = int(self._clock())
        with self._lock:
            ring = self._rings.get((broker, topic))
            if ring is not None:
                ring.add(second, n)

    def keep(self, keys: Iterable[tuple[str, str]]) -> None:
        """Watch exactly ``keys``: new pairs start empty, the others' history is kept."""
        wanted = set(keys)
        with self._lock:
            self._rings = {k: self._rings.get(k) or RateRing(self.window) for k in sorted(wanted)}

    def rows(self) -> list[tuple[str, str, list[int], int]]:
        """(broker, topic, per second for the last ``window`` complete seconds, total)."""
        last = int(self._clock()) - 1  # the current second is not over yet
        with self._lock:
            return [(b, t, ring.series(last), ring.total) for (b, t), ring in self._rings.items()]


class _CountingMqttTap(MqttTap):
    """An MQTT tap counting every message in a :class:`RateBook`; knows when it reconnected."""

    book: RateBook
    connects = 0

    def record(self, topic: str, data: bytes, mark: str | None = None) -> None:
        self.book.count(self.endpoint.broker, topic)

    def _on_connect(self, *args: Any) -> None:
        super()._on_connect(*args)
        self.connects += 1

    def needs_renewal(self) -> bool:
        """paho reconnected by itself: the new session has no subscriptions (clean start)."""
        return self.connects > 1


class _CountingKafkaTap(KafkaTap):
    """A Kafka tap counting every message in a :class:`RateBook` (librdkafka reconnects and keeps
    the assignment)."""

    book: RateBook

    def record(self, topic: str, data: bytes, mark: str | None = None) -> None:
        self.book.count(self.endpoint.broker, topic)

    def needs_renewal(self) -> bool:
        return False


_TAPS: dict[str, type[_CountingMqttTap] | type[_CountingKafkaTap]] = {
    "kafka": _CountingKafkaTap, "mosquitto": _CountingMqttTap}
RENEW_CHECK = 0.5   # seconds between two looks at whether a running tap must be renewed


class _TapRunner:
    """One target's tap in a thread of its own: connect (retrying with a backoff), count, close."""

    def __init__(self, target: RateTarget, book: RateBook, connect_timeout: float) -> None:
        self.target = target
        self.error: str | None = None
        self.watching = False
        self.tap: Tap | None = None   # the tap now (renewed after a reconnect)
        self._book, self._timeout = book, connect_timeout
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name=f"plantkg-rates-{target.endpoint.broker}",
                                       daemon=True)

    def _run(self) -> None:
        backoff = 1.0
        while not self._stop.is_set():
            tap = self.tap = _TAPS[self.target.endpoint.kind](self.target.endpoint, self.target.topics)
            tap.book = self._book
            try:
                tap.start(self._timeout)
            except Exception as exc:  # noqa: BLE001 - an unreachable broker is shown, then retried
                self.error = getattr(exc, "message", None) or str(exc) or repr(exc)
                _close(tap)
                self._stop.wait(backoff)
                backoff = min(backoff * 2, MAX_BACKOFF)
                continue
            self.error, self.watching, backoff = None, True, 1.0
            while not self._stop.wait(RENEW_CHECK) and not tap.needs_renewal():
                pass
            self.watching = False
            _close(tap)

    def stop(self) -> None:
        self._stop.set()


def _close(tap: Tap) -> None:
    try:
        tap.close()
    except Exception as exc:  # noqa: BLE001 - closing a half-started client must not kill the runner
        log.debug("closing the rate tap at %s: %r", tap.endpoint.where, exc)


class RateMonitor:
    """Keeps a tap at every target ``source()`` gives (see the module docstring)."""

    def __init__(self, source: Callable[[], tuple[DesiredState | None, ObservedState | None]], *,
                 window: int = WINDOW_S, interval: float = 1.0, connect_timeout: float = CONNECT_TIMEOUT,
                 limit: int = MAX_WATCHED) -> None:
        self.book = RateBook(window)
        self._source, self._interval, self._timeout, self._limit = source, interval, connect_timeout, limit
        self._runners: dict[RateTarget, _TapRunner] = {}
        self._retiring: list[_TapRunner] = []   # stopped, maybe still closing: joined by stop()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._seen: tuple[Any, Any] | None = None
        self._thread: threading.Thread | None = None

    def start(self) -> RateMonitor:
        self._thread = threading.Thread(target=self._watch, name="plantkg-web-rates", daemon=True)
        self._thread.start()
        return self

    def _watch(self) -> None:
        while not self._stop.is_set():
            try:
                self.retarget()
            except Exception:  # noqa: BLE001 - keep following the plant; the log says what broke
                log.exception("rate monitor: retargeting failed")
            self._stop.wait(self._interval)

    def retarget(self) -> None:
        """Start taps for new targets, stop those of targets gone (nothing when the plant and what
        runs did not change)."""
        desired, observed = self._source()
        if self._seen is not None and self._seen[0] is desired and self._seen[1] is observed:
            return
        self._seen = (desired, observed)
        targets = rate_targets(desired, observed, self._limit)
        with self._lock:
            if self._stop.is_set():
                return
            gone = [r for t, r in self._runners.items() if t not in targets]
            for target in targets:
                if target not in self._runners:
                    runner = self._runners[target] = _TapRunner(target, self.book, self._timeout)
                    runner.thread.start()
            for runner in gone:
                del self._runners[runner.target]
                runner.stop()
            self._retiring = [r for r in self._retiring if r.thread.is_alive()] + gone
            self.book.keep((t.endpoint.broker, topic) for t in targets for topic in t.topics)

    def document(self) -> dict[str, Any]:
        """The ``/api/rates`` document."""
        with self._lock:
            state = {t.endpoint.broker: r for t, r in self._runners.items()}
        topics = []
        for broker, topic, per_s, total in self.book.rows():
            runner = state.get(broker)
            topics.append({"broker": broker, "topic": topic, "per_s": per_s, "total": total,
                           "watching": bool(runner and runner.watching),
                           "error": runner.error if runner else None})
        return {"window_s": self.book.window, "enabled": True, "topics": topics}

    def threads(self) -> list[threading.Thread]:
        """The threads this monitor runs now (its own and one per tap)."""
        with self._lock:
            runners = list(self._runners.values())
            runners += self._retiring
        return [t for t in [self._thread, *(r.thread for r in runners)] if t is not None and t.is_alive()]

    def stop(self) -> None:
        """Stop following the plant and close every tap; returns once every thread has ended."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
        with self._lock:
            runners = list(self._runners.values()) + self._retiring
            self._runners.clear()
            self._retiring = []
        for runner in runners:
            runner.stop()
        for runner in runners:
            runner.thread.join()


def disabled_document(window: int = WINDOW_S) -> dict[str, Any]:
    """``/api/rates`` of a server that watches nothing (no agents: no live state)."""
    return {"window_s": window, "enabled": False, "topics": []}
