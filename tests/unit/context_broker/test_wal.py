"""The context store's write-ahead log: framing, torn tails, sequence numbers, replay after a
crash (records never applied to Oxigraph), replay of records already applied, rotation."""

from __future__ import annotations

import gc
import os
from pathlib import Path

import pyoxigraph as ox
import pytest

from engine.context_broker import store as store_mod
from engine.context_broker import wal
from engine.context_broker.app import create_app
from engine.context_broker.store import ContextStore, net_update

JSON = {"Content-Type": "application/json"}


def test_records_read_back_in_order(tmp_path: Path) -> None:
    log = wal.WriteAheadLog(tmp_path / "w.log")
    assert [log.append(p) for p in (b"a", b"", b"ccc")] == [1, 2, 3]
    log.close()
    records, torn = wal.read_records(tmp_path / "w.log")
    assert [(r.seq, r.payload) for r in records] == [(1, b"a"), (2, b""), (3, b"ccc")]
    assert torn is False


@pytest.mark.parametrize("cut", [1, wal.HEADER.size - 1, wal.HEADER.size, wal.HEADER.size + 3])
def test_a_torn_last_record_is_dropped(tmp_path: Path, cut: int) -> None:
    path = tmp_path / "w.log"
    whole = wal.encode(1, b"first") + wal.encode(2, b"second")
    path.write_bytes(whole + wal.encode(3, b"third-record")[:cut])
    records, torn = wal.read_records(path)
    assert [r.payload for r in records] == [b"first", b"second"] and torn is True


def test_a_corrupt_record_ends_the_log(tmp_path: Path) -> None:
    path = tmp_path / "w.log"
    bad = bytearray(wal.encode(2, b"second"))
    bad[-1] ^= 0xFF
    path.write_bytes(wal.encode(1, b"first") + bytes(bad) + wal.encode(3, b"third"))
    records, torn = wal.read_records(path)
    assert [r.seq for r in records] == [1] and torn is True


def test_a_gap_in_the_sequence_ends_the_log(tmp_path: Path) -> None:
    path = tmp_path / "w.log"
    path.write_bytes(wal.encode(5, b"a") + wal.encode(6, b"b") + wal.encode(8, b"c"))
    records, torn = wal.read_records(path, after=4)
    assert [r.seq for r in records] == [5, 6] and torn is True
    assert wal.read_records(path, after=5) == ([], True)


def _crash(store: ContextStore) -> None:
    """What kill -9 leaves: the log file as written, Oxigraph without what was pending."""
    assert store._wal is not None
    os.close(store._wal._fd)
    assert store._lock_fd is not None
    os.close(store._lock_fd)
    del store._store
    gc.collect()


def _writes(client: object) -> None:
    send = client.open  # type: ignore[attr-defined]
    assert send("/v2/entities", method="POST", headers=JSON, json={
        "id": "urn:ngsi-ld:AGV:1", "type": "AGV", "state": {"value": "idle"}}).status_code == 201
    for k in range(20):
        assert send("/v2/entities/urn:ngsi-ld:AGV:1/attrs", method="PATCH", headers=JSON,
                    json={"state": {"value": f"s{k}"}}).status_code == 204
    assert send("/v2/entities", method="POST", headers=JSON, json={"id": "B", "n": {"value": 1}}).status_code == 201
    assert send("/v2/entities", method="POST", headers=JSON, json={"id": "Gone"}).status_code == 201
    assert send("/v2/entities/Gone", method="DELETE").status_code == 204


def _snapshot(store: ContextStore) -> object:
    return create_app(store).test_client().get("/v2/entities?orderBy=id").json


def test_unapplied_records_are_replayed_after_a_crash(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ContextStore, "_apply_loop", lambda self: None)  # Oxigraph never gets them
    first = ContextStore(tmp_path / "d")
    _writes(create_app(first).test_client())
    expected = _snapshot(first)
    assert len(first._pending) == 24 and first._store.dump(format=ox.RdfFormat.N_QUADS) == b""
    _crash(first)
    monkeypatch.undo()
    again = ContextStore(tmp_path / "d")
    try:
        assert _snapshot(again) == expected
        assert [e["id"] for e in expected] == ["B", "urn:ngsi-ld:AGV:1"]  # type: ignore[index]
        assert expected[1]["state"]["value"] == "s19"  # type: ignore[index]
        assert (tmp_path / "d" / store_mod.WAL_FILE).stat().st_size == 0  # replayed, emptied
    finally:
        again.close()


def test_a_torn_tail_after_a_crash_loses_only_that_record(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ContextStore, "_apply_loop", lambda self: None)
    first = ContextStore(tmp_path / "d")
    _writes(create_app(first).test_client())
    expected = _snapshot(first)
    _crash(first)
    with open(tmp_path / "d" / store_mod.WAL_FILE, "ab") as f:
        f.write(wal.encode(25, b'["g",[],[["<urn:x>","<urn:p>","<urn:o>"]]]')[:-4])
    monkeypatch.undo()
    again = ContextStore(tmp_path / "d")
    try:
        assert _snapshot(again) == expected
        assert b"urn:x" not in again.nquads()
    finally:
        again.close()


def test_replaying_records_already_applied_changes_nothing(tmp_path: Path) -> None:
    changes: list[store_mod.Change] = []
    mem = ContextStore(None)
    mem._log = changes.append  # type: ignore[method-assign]  # record the changes, apply none
    _writes(create_app(mem).test_client())
    everything = ox.Store()
    everything.update(net_update(changes) or "")
    want = set(everything)
    for prefix in range(len(changes) + 1):
        partial = ox.Store()
        if prefix:
            partial.update(net_update(changes[:prefix]) or "")
        partial.update(net_update(changes) or "")
        assert set(partial) == want, prefix


def test_the_log_rotates_and_every_write_survives(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(store_mod, "ROTATE_BYTES", 2000)
    first = ContextStore(tmp_path / "d")
    client = create_app(first).test_client()
    _writes(client)
    first.sync()
    log_file = tmp_path / "d" / store_mod.WAL_FILE
    assert log_file.stat().st_size < 2000 and not log_file.with_name(log_file.name + ".old").exists()
    expected = _snapshot(first)
    graph = first.nquads()
    first.close()
    again = ContextStore(tmp_path / "d")
    try:
        assert _snapshot(again) == expected and again.nquads() == graph
    finally:
        again.close()


def test_graph_dump_shows_every_answered_write(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(ContextStore, "_apply_loop", lambda self: None)
    store = ContextStore(tmp_path / "d")
    try:
        _writes(create_app(store).test_client())
        assert b'"s19"' in store.nquads() and not store._pending
    finally:
        store.close()


def test_a_store_with_fsync_keeps_every_write(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    synced: list[int] = []
    real = os.fdatasync
    monkeypatch.setattr(os, "fdatasync", lambda fd: synced.append(fd) or real(fd))
    first = ContextStore(tmp_path / "d", fsync=True)
    _writes(create_app(first).test_client())
    assert len(synced) == 24  # one per logged write
    expected = _snapshot(first)
    first.close()
    again = ContextStore(tmp_path / "d")
    try:
        assert _snapshot(again) == expected
    finally:
        again.close()
