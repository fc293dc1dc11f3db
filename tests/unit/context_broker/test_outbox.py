"""The subscriptions' outbox (engine/context_broker/subscriptions/outbox.py): what is added and not
settled comes back at the next start, in order, also after a torn last record; compaction keeps
exactly the pending ones; and the service queues them again on start (the lanes settle what
they send)."""

from __future__ import annotations

import os
import threading
from pathlib import Path

from engine.context_broker.subscriptions.outbox import FILE_NAME, Outbox
from engine.context_broker.subscriptions.render import Outgoing


def msg(n: int, sub: str = "s1") -> Outgoing:
    return Outgoing(subscription_id=sub, body=f'{{"n": {n}, "text": "é"}}'.encode(),
                    attrs_format="normalized", service="acme", service_path="/plant",
                    entity_id=f"AGV{n}", correlator=f"c{n}")


def bodies(msgs: list[Outgoing]) -> list[bytes]:
    return [m.body for m in msgs]


def test_what_is_not_settled_comes_back_in_order(tmp_path: Path) -> None:
    box = Outbox(tmp_path)
    assert box.recover() == []
    tagged = [box.add(msg(n)) for n in range(6)]
    assert [t.outbox_id for t in tagged] == [1, 2, 3, 4, 5, 6]
    box.settle([tagged[0], tagged[3]])
    box.settle([tagged[0]])                       # settling twice is harmless
    # no close(): as after kill -9
    again = Outbox(tmp_path)
    back = again.recover()
    assert bodies(back) == bodies([tagged[n] for n in (1, 2, 4, 5)])
    assert [m.outbox_id for m in back] == [2, 3, 5, 6]
    assert back[0].entity_id == "AGV1" and back[0].service_path == "/plant" and back[0].correlator == "c1"
    # new ids continue after the recovered ones; the file now holds only what is pending
    assert again.add(msg(9)).outbox_id == 7
    again.settle(back)
    assert bodies(Outbox(tmp_path).recover()) == [msg(9).body]


def test_a_torn_last_record_is_dropped(tmp_path: Path) -> None:
    box = Outbox(tmp_path)
    box.recover()
    box.add(msg(1))
    box.add(msg(2))
    box.close()
    path = tmp_path / FILE_NAME
    size = path.stat().st_size
    with open(path, "r+b") as f:
        f.truncate(size - 3)                      # killed mid-write of the second record
    assert bodies(Outbox(tmp_path).recover()) == [msg(1).body]


def test_compaction_keeps_only_the_pending(tmp_path: Path) -> None:
    box = Outbox(tmp_path, compact_bytes=2000)
    box.recover()
    kept = []
    for n in range(200):
        tagged = box.add(msg(n))
        if n % 50 == 0:
            kept.append(tagged)
        else:
            box.settle([tagged])
    assert (tmp_path / FILE_NAME).stat().st_size < 4000  # compacted as it went
    assert not (tmp_path / (FILE_NAME + ".new")).exists()
    assert bodies(Outbox(tmp_path).recover()) == bodies(kept)


def test_adds_from_many_threads_all_come_back(tmp_path: Path) -> None:
    box = Outbox(tmp_path, compact_bytes=5000)
    box.recover()

    def work(k: int) -> None:
        for n in range(100):
            tagged = box.add(msg(k * 1000 + n, sub=f"s{k}"))
            if n % 2:
                box.settle([tagged])

    threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    back = Outbox(tmp_path).recover()
    for k in range(4):
        assert [m.entity_id for m in back if m.subscription_id == f"s{k}"] == [
            f"AGV{k * 1000 + n}" for n in range(0, 100, 2)]


def test_the_file_is_private(tmp_path: Path) -> None:
    box = Outbox(tmp_path)
    box.recover()
    box.add(msg(1))
    assert os.stat(tmp_path / FILE_NAME).st_mode & 0o077 == 0
