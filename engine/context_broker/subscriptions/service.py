"""The subscription service: registry + matching + delivery, as one part the app wires in.

``SubscriptionService(data_dir)`` gives the Flask blueprint of ``/v2/subscriptions``
(:meth:`blueprint`) and is the :class:`~engine.context_broker.contract.ChangeListener` of the
entity layer (:meth:`entity_changed`: match, render, enqueue; it never waits for a receiver).
:meth:`start` queues again what the last run left undelivered (the :class:`~.outbox.Outbox`,
``outbox.log`` in ``data_dir``) and starts the status flusher; :meth:`close` stops the lanes
(what is still queued stays in the outbox for the next start), flushes the status and closes the
MQTT and Kafka connections. As Orion 3.2+, creating a subscription sends nothing.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from engine.context_broker.contract import EntityChange, Tenant
from engine.context_broker.subscriptions import matcher, render
from engine.context_broker.subscriptions.delivery import DEFAULT_BOUND, Delivery, Sender, backoff_delay
from engine.context_broker.subscriptions.http import HttpSender
from engine.context_broker.subscriptions.model import (
    DeliveryStatus, HttpTarget, KafkaTarget, MqttTarget, PlantKafkas, Status, Subscription, Target,
)
from engine.context_broker.subscriptions.outbox import Outbox
from engine.context_broker.subscriptions.ownership import PLANTKG, Requester, lapsed
from engine.context_broker.subscriptions.parse import QParser
from engine.context_broker.subscriptions.registry import Registry
from engine.context_broker.subscriptions.result import Result

log = logging.getLogger(__name__)
STATUS_FLUSH_INTERVAL = 2.0


def _default_parse_q(text: str) -> Any:
    from engine.context_broker.q import parse_q  # the HTTP layer's q language (same grammar as GET /v2/entities)

    return parse_q(text)


class SubscriptionService:
    def __init__(self, data_dir: Path | str, *, clock: Callable[[], float] = time.time,
                 parse_q: QParser | None = None, queue_bound: int = DEFAULT_BOUND,
                 backoff: Callable[[int], float] = backoff_delay,
                 status_flush_interval: float = STATUS_FLUSH_INTERVAL,
                 senders: dict[type, Sender] | None = None, fsync: bool = False,
                 kafkas: PlantKafkas = PlantKafkas(),
                 owners: Mapping[str, Requester] | None = None) -> None:
        """``kafkas``: the plant's closed Kafka brokers, where ``kafka://`` notifications log in as
        plantkg's own principal, and those that speak TLS (:mod:`.kafka`). ``owners``: the
        broker's principals by name, as it runs (none: a subscription a principal created does
        not notify, see :func:`.ownership.lapsed`)."""
        self.clock = clock
        self._owners = dict(owners or {})
        self._lapsed_logged: set[str] = set()
        self._kafkas = kafkas
        self._parse_q = parse_q or _default_parse_q
        self.registry = Registry(Path(data_dir), self._parse_q)
        self._queries: dict[tuple[str, bool], Any] = {}
        self._last_triggered: dict[str, float] = {}
        self._trigger_lock = threading.Lock()
        self._senders: dict[type, Sender] = senders or {}
        self._sender_lock = threading.Lock()
        self.outbox = Outbox(Path(data_dir), fsync=fsync)
        self._recovered = self.outbox.recover()
        self.delivery = Delivery(self, bound=queue_bound, backoff=backoff, outbox=self.outbox)
        self._flush_interval = status_flush_interval
        self._stop = threading.Event()
        self._flusher: threading.Thread | None = None

    # --- lifecycle -----------------------------------------------------------------------
    def start(self) -> None:
        recovered, self._recovered = self._recovered, []
        gone = []
        for msg in recovered:
            sub = self.registry.current(msg.subscription_id)
            if sub is None or lapsed(sub, self._owners) is not None:  # deleted, or no longer its owner's to get
                gone.append(msg)
            else:
                self.delivery.enqueue(msg)
        self.outbox.settle(gone)
        if recovered:
            log.info("%d notification(s) left undelivered by the last run queued again (%d of "
                     "deleted or lapsed subscriptions let go)", len(recovered) - len(gone), len(gone))
        if self._flusher is None:
            self._flusher = threading.Thread(target=self._flush_loop, name="subscription-status",
                                             daemon=True)
            self._flusher.start()

    def _flush_loop(self) -> None:
        while not self._stop.wait(self._flush_interval):
            try:
                self.registry.flush_status()
            except OSError:
                log.exception("could not write the subscription status file")

    def close(self) -> None:
        self._stop.set()
        self.delivery.close()
        self.outbox.close()
        if self._flusher is not None:
            self._flusher.join(5.0)
        self.registry.flush_status()
        with self._sender_lock:
            senders, self._senders = list(self._senders.values()), {}
        for sender in senders:
            sender.close()

    def blueprint(self):  # -> flask.Blueprint
        from engine.context_broker.subscriptions.blueprint import make_blueprint

        return make_blueprint(self)

    # --- the ChangeListener --------------------------------------------------------------
    def entity_changed(self, change: EntityChange) -> None:
        """Match the change against every subscription and queue what it triggers. Called on the
        writing request's thread after the write is durable: it never raises (a subscription
        that cannot be evaluated is logged and skipped; the write has happened either way)."""
        now = self.clock()
        try:
            candidates = self.registry.candidates(change.tenant, change.entity_id)
        except Exception:  # noqa: BLE001 - a malformed change must not fail a durable write
            log.exception("could not look up the subscriptions of a change")
            return
        for sub in candidates:
            try:
                self._offer(sub, change, now)
            except Exception:  # noqa: BLE001 - one subscription must not fail a durable write
                log.exception("subscription %s: could not evaluate a change of %s", sub.id,
                              change.entity_id)

    def _offer(self, sub: Subscription, change: EntityChange, now: float) -> None:
        if not matcher.is_live(sub, now) or not matcher.triggers(sub, change, self._query(sub)):
            return
        if sub.owner is not None:
            why = lapsed(sub, self._owners)
            if why is not None:
                if sub.id not in self._lapsed_logged:
                    self._lapsed_logged.add(sub.id)
                    log.warning("subscription %s of principal %r does not notify: %s", sub.id,
                                sub.owner, why)
                return
        with self._trigger_lock:
            if matcher.throttled(sub, self._last_triggered.get(sub.id), now):
                return
            self._last_triggered[sub.id] = now
        if sub.status is Status.ONESHOT:
            self.registry.deactivate(sub.id)
        self.delivery.enqueue(render.outgoing(sub, change))

    def _query(self, sub: Subscription) -> tuple[Any, ...]:
        """The subscription's parsed q and mq (parsed once per text)."""
        out = []
        for text, metadata in ((sub.condition.q, False), (sub.condition.mq, True)):
            if text is None:
                continue
            key = (text, metadata)
            query = self._queries.get(key)
            if query is None:
                query = self._queries[key] = (self._parse_q(text, metadata=True) if metadata
                                              else self._parse_q(text))
            out.append(query)
        return tuple(out)

    # --- CRUD (called by the blueprint; ``who``: see .ownership) ------------------------
    def create(self, tenant: Tenant, doc: Any, who: Requester = PLANTKG) -> Subscription:
        return self.registry.create(tenant, doc, who)

    def update(self, sub_id: str, tenant: Tenant, patch: Any, who: Requester = PLANTKG) -> Subscription:
        sub = self.registry.update(sub_id, tenant.service, patch, who)
        with self._trigger_lock:
            self._last_triggered.pop(sub_id, None)
        if isinstance(patch, dict) and patch.get("status") == Status.INACTIVE.value:
            # deactivated by its owner: what is still queued is not sent (and counted as dropped)
            self.dropped(sub_id, self.delivery.discard(sub_id))
        return sub

    def delete(self, sub_id: str, tenant: Tenant, who: Requester = PLANTKG) -> None:
        self.registry.delete(sub_id, tenant.service, who)
        self.delivery.forget(sub_id)
        with self._trigger_lock:
            self._last_triggered.pop(sub_id, None)

    def get(self, sub_id: str, tenant: Tenant, who: Requester = PLANTKG) -> tuple[Subscription, DeliveryStatus]:
        return self.registry.get(sub_id, tenant.service, who)

    def listing(self, tenant: Tenant, path_given: bool,
                who: Requester = PLANTKG) -> list[tuple[Subscription, DeliveryStatus]]:
        return self.registry.listing(tenant.service, tenant.service_path if path_given else None, who)

    # --- delivery hooks (called by the lanes) --------------------------------------------
    def current(self, sub_id: str) -> Subscription | None:
        return self.registry.current(sub_id)

    def sender_for(self, target: Target) -> Sender:
        kind = type(target)
        with self._sender_lock:
            sender = self._senders.get(kind)
            if sender is None:
                sender = self._senders[kind] = _new_sender(kind, self._kafkas)
            return sender

    def attempted(self, sub_id: str, result: Result) -> bool:
        status = self.registry.record(sub_id, result, self.clock())
        sub = self.registry.current(sub_id)
        if status is None or sub is None:
            return False
        limit = sub.notification.max_fails_limit
        if limit is not None and status.fails_counter > limit:
            log.warning("subscription %s deactivated: failsCounter %d passes maxFailsLimit %d",
                        sub_id, status.fails_counter, limit)
            self.registry.deactivate(sub_id)
            return False
        return True

    def dropped(self, sub_id: str, count: int) -> None:
        if count:
            log.warning("subscription %s: %d notification(s) dropped", sub_id, count)
            self.registry.record_dropped(sub_id, count)


def _new_sender(kind: type, kafkas: PlantKafkas) -> Sender:
    if kind is HttpTarget:
        return HttpSender()
    if kind is MqttTarget:
        from engine.context_broker.subscriptions.mqtt import MqttSender

        return MqttSender()
    if kind is KafkaTarget:
        from engine.context_broker.subscriptions.kafka import KafkaSender

        return KafkaSender(kafkas)
    raise TypeError(f"no sender for {kind.__name__}")
