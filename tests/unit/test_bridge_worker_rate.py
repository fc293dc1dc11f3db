"""The bridge worker's forwarding rate (engine.bridge_worker.rate): a sliding window of counter
samples, its edges and a counter that starts again; and stats.json files without the field."""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import pytest

from engine.bridge_worker.rate import WINDOW, Sample, add_sample, rate
from engine.bridge_worker.stats import STATS_FILE, WorkerStats, read_stats, write_stats


def feed(points: list[tuple[float, int]], window: float = WINDOW) -> tuple[Sample, ...]:
    samples: tuple[Sample, ...] = ()
    for at, count in points:
        samples = add_sample(samples, at, count, window)
    return samples


RATE_CASES = [
    # (name, samples as (monotonic s, cumulative count), expected messages/s)
    ("no sample", [], 0.0),
    ("one sample is no measurement", [(100.0, 5000)], 0.0),
    ("steady 20/s", [(0.0, 0), (0.5, 10), (1.0, 20), (1.5, 30)], 20.0),
    ("quiet bridge", [(0.0, 7), (0.5, 7), (1.0, 7)], 0.0),
    ("a flood after a quiet start", [(0.0, 0), (0.5, 0), (1.0, 36_000)], 36_000.0),
    # a burst long ago leaves the window: only the last 10 s count
    ("burst older than the window", [(0.0, 0), (1.0, 100_000), (11.5, 100_000), (12.0, 100_005)], 10.0),
    ("sample exactly at the window's edge stays", [(0.0, 0), (10.0, 50)], 5.0),
    ("counter restart starts a new window", [(0.0, 0), (1.0, 1000), (1.5, 0), (2.0, 30)], 60.0),
    ("counter restart alone is no measurement", [(0.0, 0), (1.0, 1000), (1.5, 3)], 0.0),
    ("a clock that did not move replaces the sample", [(0.0, 0), (1.0, 10), (1.0, 20)], 20.0),
]


@pytest.mark.parametrize(("points", "expected"), [c[1:] for c in RATE_CASES], ids=[c[0] for c in RATE_CASES])
def test_rate_over_the_window(points: list[tuple[float, int]], expected: float) -> None:
    assert rate(feed(points)) == pytest.approx(expected)


def test_the_window_drops_old_samples_and_keeps_a_bounded_tuple() -> None:
    samples = feed([(t * 0.5, t * 10) for t in range(200)])  # 100 s at 20/s, a sample every 0.5 s
    assert samples[-1] == Sample(99.5, 1990)
    assert samples[0].at == pytest.approx(89.5)  # nothing older than WINDOW s before the newest
    assert len(samples) == int(WINDOW / 0.5) + 1
    assert rate(samples) == pytest.approx(20.0)


def test_a_shorter_window_forgets_sooner() -> None:
    points = [(0.0, 0), (1.0, 1000), (3.0, 1000), (4.0, 1010)]
    assert rate(feed(points, window=2.0)) == pytest.approx(10.0)
    assert rate(feed(points, window=10.0)) == pytest.approx(1010 / 4.0)


def stats(**changes: object) -> WorkerStats:
    base = WorkerStats(bridge_id="b", pid=1, ready=True, mqtt_connected=True, kafka_connected=True,
                       forwarded_mqtt_to_kafka=3, forwarded_kafka_to_mqtt=0, retried=0,
                       last_error=None, updated_at=1.0)
    return WorkerStats(**{**asdict(base), **changes})  # type: ignore[arg-type]


def test_stats_file_carries_the_rate(tmp_path: Path) -> None:
    write_stats(tmp_path, stats(forwarded_per_s=123.5))
    assert read_stats(tmp_path).forwarded_per_s == 123.5  # type: ignore[union-attr]


def test_a_stats_file_written_before_the_rate_existed_still_reads(tmp_path: Path) -> None:
    old = asdict(stats())
    del old["forwarded_per_s"]
    (tmp_path / STATS_FILE).write_text(json.dumps(old), encoding="utf-8")
    read = read_stats(tmp_path)
    assert read is not None and read.forwarded_per_s == 0.0 and read.forwarded == 3
