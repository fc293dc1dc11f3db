"""The worker's bookkeeping: PUBACKs in arrival order, lazy commits, rewinds; the stats file."""

from __future__ import annotations

from pathlib import Path

from engine.bridge_worker.ledgers import InOrderAcks, PartitionLedger
from engine.bridge_worker.stats import WorkerStats, read_stats, write_stats


def test_pubacks_leave_in_arrival_order() -> None:
    sent: list[int] = []
    acks = InOrderAcks(lambda mid, qos: sent.append(mid))
    a, b, c = (acks.add(mid, 1) for mid in (10, 11, 12))
    assert acks.confirm(c) == 0 and sent == []        # confirmed early: waits for 10 and 11
    assert acks.confirm(a) == 1 and sent == [10]
    assert acks.confirm(b) == 2 and sent == [10, 11, 12]
    assert len(acks) == 0


def test_many_in_flight_confirmed_out_of_order_from_other_threads_ack_in_arrival_order() -> None:
    """The MQTT thread adds while Kafka threads confirm, each taking every third message from the
    newest back (deliveries of different partitions come back in any order): every PUBACK leaves
    once, in the order the messages came."""
    import threading

    total = 5000
    sent: list[int] = []
    acks = InOrderAcks(lambda mid, qos: sent.append(mid))
    entries: list[object] = []
    ready = threading.Condition()

    def add_all() -> None:
        for mid in range(1, total + 1):
            entry = acks.add(mid, 1)
            with ready:
                entries.append(entry)
                ready.notify_all()

    def confirm(part: int) -> None:
        for i in range(total - 1 - part, -1, -3):
            with ready:
                ready.wait_for(lambda: len(entries) > i, timeout=30)
                entry = entries[i]
            acks.confirm(entry)  # type: ignore[arg-type]

    threads = [threading.Thread(target=add_all), *(threading.Thread(target=confirm, args=(p,)) for p in range(3))]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    assert sent == list(range(1, total + 1)) and len(acks) == 0


def test_messages_of_a_lost_connection_are_never_acked() -> None:
    sent: list[int] = []
    acks = InOrderAcks(lambda mid, qos: sent.append(mid))
    old = acks.add(1, 1)
    assert acks.connection_lost() == 1
    new = acks.add(1, 1)  # the broker sends it again, maybe with the same packet id
    assert acks.confirm(old) == 0 and sent == []
    assert acks.confirm(new) == 1 and sent == [1]


def test_commit_waits_for_every_earlier_puback_and_the_lag() -> None:
    ledger = PartitionLedger(committed=100)
    r100, r101, r102 = (ledger.sent(o) for o in (100, 101, 102))
    PartitionLedger.acked(r101, now=10.0)
    assert ledger.commit_position(now=20.0, lag=1.0) is None     # 100 not PUBACKed yet
    PartitionLedger.acked(r100, now=10.5)
    PartitionLedger.acked(r102, now=11.2)
    assert ledger.commit_position(now=11.6, lag=1.0) == 102      # 102 acked only 0.4 s ago
    assert ledger.commit_position(now=12.3, lag=1.0) == 103
    assert ledger.commit_position(now=13.0, lag=1.0) is None     # nothing new


def test_skipped_records_do_not_hold_commits_back() -> None:
    ledger = PartitionLedger(committed=0)
    ledger.skipped(0)
    PartitionLedger.acked(ledger.sent(1), now=5.0)
    assert ledger.commit_position(now=6.0, lag=1.0) == 2


def test_rewind_goes_back_to_the_last_commit() -> None:
    ledger = PartitionLedger(committed=7)
    for offset in range(7, 12):
        PartitionLedger.acked(ledger.sent(offset), now=1.0)
    assert ledger.rewind() == 7 and not ledger.records


def test_stats_file_round_trip(tmp_path: Path) -> None:
    assert read_stats(tmp_path) is None
    stats = WorkerStats("b", 42, True, True, None, 3, 4, 1, "boom", 123.5)
    write_stats(tmp_path, stats)
    assert read_stats(tmp_path) == stats and stats.forwarded == 7
    (tmp_path / "stats.json").write_text('{"bridge_id": "b"}')
    assert read_stats(tmp_path) is None
