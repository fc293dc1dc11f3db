"""The desired-state cache: a hit gives what derive gave; any edit of an input misses."""

from __future__ import annotations

import shutil
from pathlib import Path

from engine.incremental.desired_cache import DesiredCache
from engine.pipeline import run_pipeline

ROOT = Path(__file__).resolve().parents[2]
CELL = ROOT / "ontology" / "examples" / "robot-cell.ttl"


def test_hit_equals_fresh_derive_and_edits_miss(tmp_path: Path) -> None:
    cache = DesiredCache(tmp_path / "cache")
    plant = tmp_path / "cell.ttl"
    shutil.copy(CELL, plant)
    cold = run_pipeline([plant], None, observe=False, cache=cache)
    assert cold.plant is not None and "load" in cold.timings
    warm = run_pipeline([plant], None, observe=False, cache=cache)
    assert warm.plant is None and "load" not in warm.timings  # nothing was parsed or reasoned
    assert warm.desired == cold.desired
    assert warm.report.conforms and warm.report.results == cold.report.results
    plant.write_text(plant.read_text().replace("pk:port 1883", "pk:port 1884", 1))
    edited = run_pipeline([plant], None, observe=False, cache=cache)
    assert edited.plant is not None  # a miss: recomputed
    assert {b.port for b in edited.desired.brokers} == {1884, 9092}


def test_invalid_plant_is_never_cached(tmp_path: Path) -> None:
    cache = DesiredCache(tmp_path / "cache")
    plant = tmp_path / "cell.ttl"
    plant.write_text(CELL.read_text().replace("pk:port 1883", "pk:port 0", 1))
    assert not run_pipeline([plant], None, observe=False, cache=cache).valid
    assert not list((tmp_path / "cache").glob("*.json"))
    again = run_pipeline([plant], None, observe=False, cache=cache)
    assert again.plant is not None and not again.valid


def test_unreadable_entry_is_a_miss(tmp_path: Path) -> None:
    cache = DesiredCache(tmp_path / "cache")
    run_pipeline([CELL], None, observe=False, cache=cache)
    (entry,) = (tmp_path / "cache").glob("*.json")
    entry.write_text("{not json")
    assert run_pipeline([CELL], None, observe=False, cache=cache).plant is not None
