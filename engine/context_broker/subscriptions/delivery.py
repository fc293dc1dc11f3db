"""Delivery lanes: each subscription's notifications in order, none waiting for another's receiver.

A :class:`Lane` per subscription holds a bounded queue and, while it has work, one thread that
sends the head of the queue. A temporary failure keeps that notification at the head and retries
it after :func:`backoff_delay` (0.5 s doubling to 30 s), until it is sent, the subscription is
deleted or deactivated, or the service closes; so order is kept and nothing is skipped while a
receiver is down. A sender that can pipeline (``send_many``: MQTT publishes up to :data:`WINDOW`
messages before it waits for their acknowledgements) gets the first ``WINDOW`` queued
notifications at once and answers one result per message in order, stopping at the first failure;
the lane retries from there (so a message after a lost acknowledgement may arrive twice: delivery
is at least once, as it is for one message at a time). A permanent failure (see :mod:`.result`) is counted and let go. Each attempt
uses the subscription's *current* target, so a ``PATCH`` of a wrong URL unblocks a lane.

Bounded: past ``bound`` queued notifications the oldest is dropped and counted
(``droppedNotifications`` on the subscription). Every notification is handed to ``settle`` once
the lane is done with it (sent, refused for good, dropped or discarded): the service's
:class:`~.outbox.Outbox` logs it as settled, so what is still queued at a kill -9 or a stop is
sent again at the next start.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Protocol

from engine.context_broker.subscriptions.model import Subscription, Target
from engine.context_broker.subscriptions.outbox import Outbox
from engine.context_broker.subscriptions.render import Outgoing
from engine.context_broker.subscriptions.result import Result

BACKOFF_BASE = 0.5
BACKOFF_CAP = 30.0
DEFAULT_BOUND = 10_000
#: How long an idle lane's thread waits for more work before it ends (a busy subscription keeps
#: its thread; an idle one holds none).
LINGER = 5.0
#: Notifications handed at once to a sender that pipelines (``send_many``).
WINDOW = 64


def backoff_delay(attempt: int, base: float = BACKOFF_BASE, cap: float = BACKOFF_CAP) -> float:
    """Seconds before retry number ``attempt`` (1, 2, ...): base, 2 base, 4 base, ... at most cap."""
    if attempt < 1:
        return 0.0
    return min(cap, base * 2 ** min(attempt - 1, 62))


class Sender(Protocol):
    def send(self, target, msg: Outgoing) -> Result: ...  # type: ignore[no-untyped-def]
    def close(self) -> None: ...


class PipeliningSender(Sender, Protocol):
    def send_many(self, target, msgs: list[Outgoing]) -> list[Result]: ...  # type: ignore[no-untyped-def]
    """One result per message, in order, ending with the first failure (the rest not tried)."""


class Hooks(Protocol):
    """What the lanes need from the service (the registry and the senders behind it)."""

    def current(self, sub_id: str) -> Subscription | None: ...
    def sender_for(self, target: Target) -> Sender: ...
    def attempted(self, sub_id: str, result: Result) -> bool: ...   # False: stop this lane's queue
    def dropped(self, sub_id: str, count: int) -> None: ...


class Lane:
    def __init__(self, sub_id: str, hooks: Hooks, stop: threading.Event, bound: int,
                 backoff: Callable[[int], float],
                 settle: Callable[[list[Outgoing]], None] = lambda _msgs: None) -> None:
        self.sub_id = sub_id
        self._settle = settle
        self._hooks = hooks
        self._stop = stop
        self._bound = bound
        self._backoff = backoff
        self._lock = threading.Lock()
        self._more = threading.Condition(self._lock)
        self._queue: deque[Outgoing] = deque()
        self._thread: threading.Thread | None = None
        self._sending = 0   # how many at the head a send is under way for: never dropped
        self._wake = threading.Event()

    def put(self, msg: Outgoing) -> None:
        dropped: list[Outgoing] = []
        with self._lock:
            self._queue.append(msg)
            while len(self._queue) > self._bound and len(self._queue) > self._sending:
                dropped.append(self._queue[self._sending])
                del self._queue[self._sending]   # the oldest not being sent
            self._more.notify()
            if self._thread is None and not self._stop.is_set():
                self._thread = threading.Thread(target=self._run, name=f"notify-{self.sub_id}",
                                                daemon=True)
                self._thread.start()
        if dropped:
            self._settle(dropped)
            self._hooks.dropped(self.sub_id, len(dropped))

    def pending(self) -> int:
        with self._lock:
            return len(self._queue)

    def discard(self) -> int:
        """Throw away what is queued (subscription deleted or deactivated); returns how many."""
        with self._lock:
            thrown = list(self._queue)
            self._queue.clear()
        self._wake.set()
        self._settle(thrown)
        return len(thrown)

    def join(self, timeout: float) -> None:
        thread = self._thread
        self._wake.set()
        with self._more:
            self._more.notify_all()
        if thread is not None:
            thread.join(timeout)

    def _head(self, count: int = 1) -> list[Outgoing] | None:
        """The first ``count`` queued (at least one), marked as being sent; None: no more work."""
        with self._more:
            deadline = time.monotonic() + LINGER
            while not self._queue and not self._stop.is_set():
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    break
                self._more.wait(remaining)
            if not self._queue or self._stop.is_set():
                self._thread = None
                self._sending = 0
                return None
            batch = [self._queue[i] for i in range(min(count, len(self._queue)))]
            self._sending = len(batch)
            return batch

    def _pop(self, msg: Outgoing) -> None:
        with self._lock:
            if self._queue and self._queue[0] is msg:
                self._queue.popleft()
                self._sending = max(0, self._sending - 1)
            else:
                return  # discarded meanwhile (and settled then)
        self._settle([msg])

    def _release(self) -> None:
        with self._lock:
            self._sending = 0

    def _run(self) -> None:
        attempt = 0
        window = 1
        while (batch := self._head(window)) is not None:
            sub = self._hooks.current(self.sub_id)
            if sub is None:
                self.discard()
                self._release()
                continue
            target = sub.notification.target
            sender = self._hooks.sender_for(target)
            many = getattr(sender, "send_many", None)
            window = WINDOW if many is not None else 1
            results = many(target, batch) if many is not None else [sender.send(target, batch[0])]
            for msg, result in zip(batch, results):
                keep_going = self._hooks.attempted(self.sub_id, result)
                if result.ok or not result.retry:
                    self._pop(msg)
                    attempt = 0
                if not keep_going:  # deactivated (maxFailsLimit): what is left will not be sent
                    self._release()
                    self._hooks.dropped(self.sub_id, self.discard())
                    break
                if result.retry and not result.ok:
                    self._release()
                    attempt += 1
                    self._wake.clear()
                    self._wake.wait(self._backoff(attempt))
                    break
            self._release()


class Delivery:
    """The lanes of all subscriptions."""

    def __init__(self, hooks: Hooks, *, bound: int = DEFAULT_BOUND,
                 backoff: Callable[[int], float] = backoff_delay,
                 outbox: Outbox | None = None) -> None:
        self._hooks = hooks
        self._outbox = outbox
        self._settle: Callable[[list[Outgoing]], None] = (
            outbox.settle if outbox is not None else (lambda _msgs: None))
        self._bound = bound
        self._backoff = backoff
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._lanes: dict[str, Lane] = {}

    def enqueue(self, msg: Outgoing) -> None:
        """Queue ``msg`` on its subscription's lane, logged in the outbox first (a notification
        recovered from the outbox carries its id already and is not logged again)."""
        if self._outbox is not None and not msg.outbox_id:
            msg = self._outbox.add(msg)
        with self._lock:
            lane = self._lanes.get(msg.subscription_id)
            if lane is None:
                lane = self._lanes[msg.subscription_id] = Lane(
                    msg.subscription_id, self._hooks, self._stop, self._bound, self._backoff,
                    self._settle)
        lane.put(msg)

    def forget(self, sub_id: str) -> None:
        with self._lock:
            lane = self._lanes.pop(sub_id, None)
        if lane is not None:
            lane.discard()

    def discard(self, sub_id: str) -> int:
        lane = self._lanes.get(sub_id)
        return lane.discard() if lane else 0

    def pending(self, sub_id: str) -> int:
        lane = self._lanes.get(sub_id)
        return lane.pending() if lane else 0

    def close(self, timeout: float = 10.0) -> None:
        self._stop.set()
        with self._lock:
            lanes = list(self._lanes.values())
        for lane in lanes:
            lane.join(timeout)
