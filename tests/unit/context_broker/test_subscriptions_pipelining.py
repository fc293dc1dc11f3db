"""A sender that pipelines (``send_many``, as MQTT does) gets the lane's queued notifications in
windows, in order; a failure inside a window is retried from that notification on, so nothing is
skipped and the order of first deliveries is the order of changes."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from engine import process
from engine.context_broker.contract import Tenant
from engine.context_broker.subscriptions import SubscriptionService
from engine.context_broker.subscriptions.delivery import WINDOW
from engine.context_broker.subscriptions.model import HttpTarget
from engine.context_broker.subscriptions.result import Result

from .sub_helpers import change, doc, entity

URL = "http://127.0.0.1:1/pipelined"


class PipeliningSender:
    """Answers each window message by message; ``fail_at`` = (call number, index) answers a
    temporary failure there. The first call blocks until ``release`` so changes queue up."""

    def __init__(self, fail_at: tuple[int, int]) -> None:
        self.fail_at = fail_at
        self.calls: list[list[int]] = []
        self.ok: list[int] = []
        self.release = threading.Event()
        self.lock = threading.Lock()

    def send(self, target: HttpTarget, msg: Any) -> Result:  # pragma: no cover - not used by lanes
        return self.send_many(target, [msg])[0]

    def send_many(self, target: HttpTarget, msgs: list[Any]) -> list[Result]:
        self.release.wait(30)
        values = [json.loads(m.body)["data"][0]["temperature"]["value"] for m in msgs]
        results = []
        with self.lock:
            self.calls.append(values)
            for index, value in enumerate(values):
                if (len(self.calls), index) == self.fail_at:
                    results.append(Result.temporary("no PUBACK"))
                    break
                self.ok.append(value)
                results.append(Result.success())
        return results

    def close(self) -> None:
        self.release.set()


@pytest.fixture
def sender() -> PipeliningSender:
    return PipeliningSender(fail_at=(2, 3))


@pytest.fixture
def service(tmp_path: Path, sender: PipeliningSender) -> Iterator[SubscriptionService]:
    svc = SubscriptionService(tmp_path, backoff=lambda attempt: 0.01, senders={HttpTarget: sender})
    svc.start()
    yield svc
    sender.release.set()
    svc.close()


def test_windows_in_order_and_a_failure_retried_from_where_it_happened(service, sender) -> None:
    sub = service.create(Tenant(), doc(notification={"http": {"url": URL}}))
    count = WINDOW + 20
    for value in range(count):
        service.entity_changed(change(entity(temperature=value)))
    sender.release.set()
    process.wait_until(lambda: len(sender.ok) == count, 10.0, 0.005, what="every notification")
    assert sender.ok == list(range(count)), "each delivered once, in change order"
    first, second, third = sender.calls[:3]
    assert first == [0]                                   # the lane starts one at a time
    assert len(second) > 1 and second[0] == 1            # then a window of what queued meanwhile
    assert len(second) <= WINDOW
    assert third[0] == second[3], "the retry starts at the notification that failed"
    # the lane records a result after the sender has returned it: wait for the last record
    status = process.wait_until(
        lambda: (st := service.get(sub.id, Tenant())[1]).times_sent >= count + 1 and st, 10.0, 0.005,
        what="the delivery status of every attempt")
    assert status.times_sent == count + 1 and status.fails_counter == 0
