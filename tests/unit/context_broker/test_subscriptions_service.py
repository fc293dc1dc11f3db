"""The subscription service's logic with a fake clock and an in-process sender: throttling,
expiry, oneshot, no initial notification, retries in order with the failure visible, permanent
failures let go, bounded queues that count what they drop, maxFailsLimit, durability across a
restart, the backoff schedule. (Real receivers: tests/integration/test_context_broker_notifications.py.)"""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from engine import process
from engine.context_broker.contract import NgsiError, Tenant
from engine.context_broker.subscriptions import SubscriptionService
from engine.context_broker.subscriptions.delivery import backoff_delay
from engine.context_broker.subscriptions.model import HttpTarget, render
from engine.context_broker.subscriptions.result import Result

from .sub_helpers import change, doc, entity


class FakeClock:
    def __init__(self, now: float = 1_800_000_000.0) -> None:
        self.now = now

    def __call__(self) -> float:
        return self.now


class ScriptedSender:
    """Records every attempt per URL; answers from a per-URL script of Results (then success);
    a URL in ``blocked`` waits on ``release`` before answering."""

    def __init__(self) -> None:
        self.attempts: dict[str, list[Any]] = {}
        self.script: dict[str, list[Result]] = {}
        self.blocked: set[str] = set()
        self.release = threading.Event()
        self.entered = threading.Event()  # set when a blocked send has begun
        self.lock = threading.Lock()

    def send(self, target: HttpTarget, msg) -> Result:
        if target.url in self.blocked:
            self.entered.set()
            self.release.wait(30)
        with self.lock:
            self.attempts.setdefault(target.url, []).append(json.loads(msg.body))
            script = self.script.get(target.url) or []
            return script.pop(0) if script else Result.success(204)

    def close(self) -> None:
        self.release.set()

    def values(self, url: str, attr: str = "temperature") -> list[Any]:
        with self.lock:
            return [m["data"][0][attr]["value"] for m in self.attempts.get(url, [])]


URL_A, URL_B = "http://127.0.0.1:1/a", "http://127.0.0.1:1/b"


@pytest.fixture
def clock() -> FakeClock:
    return FakeClock()


@pytest.fixture
def sender() -> ScriptedSender:
    return ScriptedSender()


@pytest.fixture
def service(tmp_path: Path, clock: FakeClock, sender: ScriptedSender) -> Iterator[SubscriptionService]:
    svc = SubscriptionService(tmp_path, clock=clock, backoff=lambda attempt: 0.01,
                              senders={HttpTarget: sender}, queue_bound=50)
    svc.start()
    yield svc
    sender.release.set()
    svc.close()


def http_doc(url: str = URL_A, **extra: Any) -> dict[str, Any]:
    return doc(notification={"http": {"url": url}}, **extra)


def wait_for(predicate, what: str, deadline: float = 10.0) -> None:
    process.wait_until(predicate, deadline, 0.005, what=what)


def shown(svc: SubscriptionService, sub_id: str) -> dict[str, Any]:
    sub, status = svc.get(sub_id, Tenant())
    return render(sub, status, svc.clock())


def test_no_initial_notification_and_one_per_change(service, sender) -> None:
    sub = service.create(Tenant(), http_doc())
    assert service.delivery.pending(sub.id) == 0 and sender.attempts == {}
    for t in (20, 21, 22):
        service.entity_changed(change(entity(temperature=t)))
    wait_for(lambda: len(sender.values(URL_A)) == 3, "three notifications")
    assert sender.values(URL_A) == [20, 21, 22]
    assert shown(service, sub.id)["notification"]["timesSent"] == 3


def test_throttling_discards_inside_the_guard_period(service, sender, clock) -> None:
    service.create(Tenant(), http_doc(throttling=5))
    service.entity_changed(change(entity(temperature=1)))
    clock.now += 4.9
    service.entity_changed(change(entity(temperature=2)))      # inside the guard: discarded
    clock.now += 0.1
    service.entity_changed(change(entity(temperature=3)))
    wait_for(lambda: len(sender.values(URL_A)) == 2, "two notifications")
    assert sender.values(URL_A) == [1, 3]


def test_expired_subscription_stays_silent_and_shows_expired(service, sender, clock) -> None:
    sub = service.create(Tenant(), http_doc(expires="2027-01-15T08:00:00Z"))
    clock.now = 1_800_000_000.0 - 1  # 2027-01-15T07:59:59Z
    service.entity_changed(change(entity(temperature=1)))
    wait_for(lambda: len(sender.values(URL_A)) == 1, "the notification before expiry")
    clock.now += 1
    service.entity_changed(change(entity(temperature=2)))
    assert service.delivery.pending(sub.id) == 0 and sender.values(URL_A) == [1]
    assert shown(service, sub.id)["status"] == "expired"


def test_oneshot_fires_once_then_is_inactive_durably(service, sender, tmp_path) -> None:
    sub = service.create(Tenant(), http_doc(status="oneshot"))
    service.entity_changed(change(entity(temperature=1)))
    service.entity_changed(change(entity(temperature=2)))
    wait_for(lambda: len(sender.values(URL_A)) == 1, "the one notification")
    assert shown(service, sub.id)["status"] == "inactive"
    stored = json.loads((tmp_path / "subscriptions.json").read_text())
    assert stored["subscriptions"][0]["doc"]["status"] == "inactive"
    service.update(sub.id, Tenant(), {"status": "oneshot"})
    service.entity_changed(change(entity(temperature=3)))
    wait_for(lambda: len(sender.values(URL_A)) == 2, "the second oneshot notification")
    assert sender.values(URL_A) == [1, 3]


def test_temporary_failures_are_retried_in_order_and_shown(service, sender) -> None:
    sub = service.create(Tenant(), http_doc())
    sender.script[URL_A] = [Result.temporary("Couldn't connect to server")] * 3
    sender.blocked.add(URL_A)
    for t in (1, 2):
        service.entity_changed(change(entity(temperature=t)))
    sender.release.set()
    wait_for(lambda: sender.values(URL_A)[-1:] == [2], "both delivered")
    assert sender.values(URL_A) == [1, 1, 1, 1, 2]
    view = shown(service, sub.id)
    assert view["status"] == "active" and "failsCounter" not in view["notification"]
    assert view["notification"]["lastFailureReason"] == "Couldn't connect to server"
    assert view["notification"]["timesSent"] == 5


def test_failed_while_failing(service, sender) -> None:
    sub = service.create(Tenant(), http_doc())
    sender.script[URL_A] = [Result.temporary("HTTP 503 from the receiver", 503)] * 10_000
    service.entity_changed(change(entity(temperature=1)))
    wait_for(lambda: len(sender.values(URL_A)) >= 3, "three attempts")
    view = shown(service, sub.id)
    assert view["status"] == "failed" and view["notification"]["failsCounter"] >= 3
    assert "lastSuccess" not in view["notification"]
    sender.script[URL_A] = []
    wait_for(lambda: shown(service, sub.id)["status"] == "active", "back to active")
    assert shown(service, sub.id)["notification"]["lastSuccessCode"] == 204


def test_permanent_failure_is_counted_and_let_go(service, sender) -> None:
    sub = service.create(Tenant(), http_doc())
    sender.script[URL_A] = [Result.permanent("HTTP 404 from the receiver", 404)]
    service.entity_changed(change(entity(temperature=1)))
    wait_for(lambda: len(sender.values(URL_A)) == 1, "the refused notification")
    assert shown(service, sub.id)["notification"]["failsCounter"] == 1
    service.entity_changed(change(entity(temperature=2)))
    wait_for(lambda: len(sender.values(URL_A)) == 2, "the next notification")
    assert sender.values(URL_A) == [1, 2]
    assert "failsCounter" not in shown(service, sub.id)["notification"]


def test_a_blocked_receiver_does_not_hold_up_another_subscription(service, sender) -> None:
    service.create(Tenant(), http_doc(URL_A))
    service.create(Tenant(), http_doc(URL_B))
    sender.blocked.add(URL_A)
    for t in (1, 2, 3):
        service.entity_changed(change(entity(temperature=t)))
    wait_for(lambda: len(sender.values(URL_B)) == 3, "the other subscription's notifications")
    assert sender.values(URL_A) == []
    sender.release.set()
    wait_for(lambda: len(sender.values(URL_A)) == 3, "the blocked one catches up")
    assert sender.values(URL_A) == [1, 2, 3]


def test_full_queue_drops_the_oldest_and_counts_them(tmp_path, clock, sender) -> None:
    svc = SubscriptionService(tmp_path, clock=clock, backoff=lambda a: 0.01,
                              senders={HttpTarget: sender}, queue_bound=3)
    try:
        sub = svc.create(Tenant(), http_doc())
        sender.blocked.add(URL_A)
        svc.entity_changed(change(entity(temperature=0)))
        assert sender.entered.wait(10), "the first notification's send did not begin"
        for t in range(1, 10):
            svc.entity_changed(change(entity(temperature=t)))
        assert shown(svc, sub.id)["notification"]["droppedNotifications"] == 7
        sender.release.set()
        wait_for(lambda: len(sender.values(URL_A)) == 3, "the kept notifications")
        assert sender.values(URL_A) == [0, 8, 9]  # the one in flight, then the newest
    finally:
        sender.release.set()
        svc.close()


def test_max_fails_limit_deactivates(service, sender) -> None:
    sub = service.create(Tenant(), doc(notification={"http": {"url": URL_A}, "maxFailsLimit": 2}))
    sender.script[URL_A] = [Result.temporary("down")] * 100
    service.entity_changed(change(entity(temperature=1)))
    wait_for(lambda: "droppedNotifications" in shown(service, sub.id)["notification"], "deactivation")
    view = shown(service, sub.id)
    assert view["status"] == "inactive" and view["notification"]["droppedNotifications"] == 1
    assert len(sender.values(URL_A)) == 3


def test_subscriptions_and_counters_survive_a_restart(tmp_path, clock, sender) -> None:
    svc = SubscriptionService(tmp_path, clock=clock, senders={HttpTarget: sender})
    sub = svc.create(Tenant("acme", "/plant"), http_doc(description="kept"))
    svc.entity_changed(change(entity(temperature=1), tenant=Tenant("acme", "/plant")))
    wait_for(lambda: len(sender.values(URL_A)) == 1, "one notification")
    wait_for(lambda: svc.registry.status_of(sub.id).times_sent == 1, "the counter")
    svc.close()
    again = SubscriptionService(tmp_path, clock=clock, senders={HttpTarget: sender})
    try:
        view = shown_tenant(again, sub.id, Tenant("acme", "/plant"))
        assert view["description"] == "kept" and view["notification"]["timesSent"] == 1
        with pytest.raises(NgsiError) as info:
            again.get(sub.id, Tenant("other"))
        assert info.value.status == 404
    finally:
        again.close()


def shown_tenant(svc: SubscriptionService, sub_id: str, tenant: Tenant) -> dict[str, Any]:
    sub, status = svc.get(sub_id, tenant)
    return render(sub, status, svc.clock())


def test_backoff_schedule() -> None:
    assert [backoff_delay(n) for n in range(0, 9)] == [0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 30.0, 30.0]
    assert backoff_delay(10_000) == 30.0
    assert backoff_delay(3, base=1.0, cap=3.0) == 3.0


def test_deactivating_drops_what_is_queued(service, sender) -> None:
    sub = service.create(Tenant(), http_doc())
    sender.script[URL_A] = [Result.temporary("down")] * 10_000
    for t in (1, 2, 3):
        service.entity_changed(change(entity(temperature=t)))
    wait_for(lambda: len(sender.values(URL_A)) >= 2, "retries")
    service.update(sub.id, Tenant(), {"status": "inactive"})
    assert service.delivery.pending(sub.id) == 0
    assert shown(service, sub.id)["notification"]["droppedNotifications"] == 3


@pytest.mark.parametrize("content,problem", [
    ("{", "not a subscriptions file"),
    ('{"version": 1, "subscriptions": [{"id": "ab", "service": "", "servicePath": "/", "doc": {}}]}',
     "subscription ab is not valid: empty payload"),
])
def test_a_damaged_store_is_refused_naming_the_file(tmp_path, content, problem) -> None:
    from engine.context_broker.subscriptions.registry import SubscriptionStoreError

    (tmp_path / "subscriptions.json").write_text(content)
    with pytest.raises(SubscriptionStoreError) as info:
        SubscriptionService(tmp_path)
    assert str(tmp_path / "subscriptions.json") in str(info.value) and problem in str(info.value)


def test_a_change_that_cannot_be_rendered_does_not_fail_the_write(service, sender) -> None:
    service.create(Tenant(), http_doc())
    broken = change({"id": "Room1"}, changed={"temperature"})   # no type: matching raises KeyError
    service.entity_changed(broken)                               # logged, not raised
    service.entity_changed(change(entity(temperature=5)))
    wait_for(lambda: len(sender.values(URL_A)) >= 1, "the next notification")
    assert sender.values(URL_A) == [5]


def test_candidates_index_exact_ids_and_scan_patterns(service) -> None:
    exact = service.create(Tenant(), doc(subject={"entities": [{"id": "A1"}, {"id": "A2", "type": "T"}]}))
    pattern = service.create(Tenant(), doc(subject={"entities": [{"id": "B1"}, {"idPattern": "^A"}]}))
    other = service.create(Tenant("acme"), doc(subject={"entities": [{"id": "A1"}]}))
    ids = lambda tenant, entity_id: {s.id for s in service.registry.candidates(tenant, entity_id)}  # noqa: E731
    assert ids(Tenant(), "A1") == ids(Tenant(), "A2") == {exact.id, pattern.id}
    assert ids(Tenant(), "Z9") == {pattern.id}
    assert ids(Tenant("acme"), "A1") == {other.id} and ids(Tenant("nobody"), "A1") == set()
    service.delete(exact.id, Tenant())
    assert ids(Tenant(), "A1") == {pattern.id}


def test_a_failed_write_changes_nothing(service, tmp_path) -> None:
    kept = service.create(Tenant(), http_doc(description="kept"))
    (tmp_path / "subscriptions.json").unlink()
    (tmp_path / "subscriptions.json").mkdir()              # the rename over it now fails
    try:
        for attempt in (lambda: service.create(Tenant(), http_doc()),
                        lambda: service.update(kept.id, Tenant(), {"description": "changed"}),
                        lambda: service.delete(kept.id, Tenant())):
            with pytest.raises(NgsiError) as info:
                attempt()
            assert info.value.status == 500 and "nothing was changed" in info.value.description
        assert [s.description for s, _ in service.listing(Tenant(), False)] == ["kept"]
    finally:
        (tmp_path / "subscriptions.json").rmdir()
