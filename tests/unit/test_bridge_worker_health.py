"""Counters go on across a worker's runs: the next run starts where the last snapshot left them."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from engine.bridge_worker.health import Health
from engine.bridge_worker.ngsi_health import NgsiHealth
from engine.bridge_worker.stats import WorkerStats, read_stats, write_stats


def previous(bridge_id: str = "b1", **counters: int) -> WorkerStats:
    base = WorkerStats(bridge_id=bridge_id, pid=1, ready=True, mqtt_connected=True, kafka_connected=True,
                       forwarded_mqtt_to_kafka=0, forwarded_kafka_to_mqtt=0, retried=0,
                       last_error="old error", updated_at=0.0)
    return dataclasses.replace(base, **counters)


def test_kafka_counters_start_from_the_last_snapshot_and_flags_do_not() -> None:
    health = Health("b1")
    health.carry_on_from(previous(forwarded_mqtt_to_kafka=120, forwarded_kafka_to_mqtt=7, retried=3))
    health.count("forwarded_mqtt_to_kafka")
    snap = health.snapshot(needs_subscription=False, needs_assignment=False, stopping=False)
    assert (snap.forwarded_mqtt_to_kafka, snap.forwarded_kafka_to_mqtt, snap.retried) == (121, 7, 3)
    assert snap.forwarded == 128
    # connection state and the last error belong to the run that saw them
    assert (snap.mqtt_connected, snap.kafka_connected, snap.last_error, snap.ready) == (False, None, None, False)


def test_ngsi_counters_start_from_the_last_snapshot() -> None:
    health = NgsiHealth("b1")
    health.carry_on_from(previous(mechanism="mqtt-ngsi", forwarded_mqtt_to_ngsi=40, refused=2, skipped=5))
    health.count("refused")
    snap = health.ngsi_snapshot(needs_subscription=False, needs_ngsi_subscriptions=False, stopping=False)
    assert (snap.forwarded_mqtt_to_ngsi, snap.refused, snap.skipped) == (40, 3, 5)


def test_another_bridges_snapshot_or_none_starts_from_zero() -> None:
    for before in (previous("someone-else", forwarded_mqtt_to_kafka=99), None):
        health = Health("b1")
        health.carry_on_from(before)
        snap = health.snapshot(needs_subscription=False, needs_assignment=False, stopping=False)
        assert snap.forwarded == 0 and snap.retried == 0


def test_the_snapshot_read_back_from_its_file_carries_on(tmp_path: Path) -> None:
    write_stats(tmp_path, previous(forwarded_kafka_to_mqtt=512))
    health = Health("b1")
    health.carry_on_from(read_stats(tmp_path))
    assert health.snapshot(needs_subscription=False, needs_assignment=False, stopping=False).forwarded == 512
