"""The warm pipeline (engine.incremental.warm) answers as run_pipeline does, call after call, and
starts cold only when it must: first, after a call that raised, for an owner only the caller names."""

from __future__ import annotations

from pathlib import Path

import pytest

from benchmarks import synthetic
from engine.incremental.warm import WarmPipeline
from engine.pipeline import Pipeline, run_pipeline
from kg.errors import InputError, RdfSyntaxError
from tests.unit.fake_agents import FakeFleet

N = 40


@pytest.fixture(autouse=True)
def own_cache(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PLANTKG_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "plantkg-cache"))


def _same(got: Pipeline, full: Pipeline) -> None:
    assert got.report.conforms == full.report.conforms
    assert sorted(r.key() for r in got.report.results) == sorted(r.key() for r in full.report.results)
    assert got.desired == full.desired
    assert got.plan == full.plan


def test_edits_and_a_new_file_answer_as_a_cold_run(tmp_path: Path) -> None:
    path = synthetic.write_file(N, tmp_path)
    warm = WarmPipeline()
    _same(warm([path], observe=False), run_pipeline([path], observe=False))
    text = path.read_text()
    path.write_text(text.replace('pk:name "Sensor 7"', 'pk:name "Sensor 7 (moved)"'))
    _same(warm([path], observe=False), run_pipeline([path], observe=False))
    joined = tmp_path / "vehicles.ttl"
    joined.write_text(synthetic.HEADER.split(":type-sensor")[0]
                      + ':agv a pk:Resource ; pk:id "agv-1" ; pk:name "AGV" ; pk:sendsTo :broker0 ; '
                        "pk:subscribes :topic1 .\n:broker0 pk:hasTopic :topic1 .\n")
    _same(warm([path, joined], observe=False), run_pipeline([path, joined], observe=False))
    path.write_text(text.replace('pk:id "res-3"', 'pk:id "res-4"'))  # a duplicate id: invalid
    got = warm([path, joined], observe=False)
    _same(got, run_pipeline([path, joined], observe=False))
    assert not got.valid and got.desired is None
    assert warm.stats == {"cold": 1, "warm": 3}


def test_a_call_that_raises_spends_the_session_and_the_next_starts_cold(tmp_path: Path) -> None:
    path = synthetic.write_file(N, tmp_path)
    warm = WarmPipeline()
    warm([path], observe=False)
    good = path.read_text()
    path.write_text(good + ":x a pk:Resource , .\n")
    with pytest.raises(RdfSyntaxError) as raised:
        warm([path], observe=False)
    assert str(path) in str(raised.value)
    empty = tmp_path / "empty.ttl"
    empty.write_text("")
    path.write_text(good)
    with pytest.raises(InputError, match="holds no triples"):
        warm([path, empty], observe=False)  # a cold start refuses it as loading does
    _same(warm([path], observe=False), run_pipeline([path], observe=False))
    assert warm.stats == {"cold": 2, "warm": 0}  # the failed calls count nothing; the last started afresh


def test_it_observes_and_plans_against_the_agents_with_the_callers_owner(tmp_path: Path) -> None:
    fleet = FakeFleet()
    path = synthetic.write_file(N, tmp_path)
    directory = fleet.directory()
    warm = WarmPipeline()
    got = warm([path], directory, owner="cell-7")
    full = run_pipeline([path], directory, owner="cell-7")
    assert got.desired is not None and got.desired.owner == "cell-7"
    _same(got, full)
    assert got.plan is not None and got.plan.pending and got.observed == full.observed
    assert {"observe", "plan"} <= set(got.timings)
