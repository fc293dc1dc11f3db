"""The reconcile loop's logic with the agents' test double and a stub pipeline (no broker, no
reasoner): which files it watches, what a change is, debouncing, one apply at a time, an invalid
or ownerless plant never applied. The real thing runs in tests/integration/test_reconcile_loop.py.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path
from typing import Any

import pytest

from engine import process
from engine.apply import apply
from engine.model import BrokerSpec, DesiredState, TopicSpec
from engine.observed import observe
from engine.pipeline import Pipeline
from engine.plan import plan as make_plan
from engine.reconcile_loop import ReconcileLoop, content_digest, plant_files
from kg.validate import ValidationReport, ValidationResult
from tests.unit.fake_agents import FakeFleet

OWNER = "plant-x"
BROKER = BrokerSpec("m1", "urn:x:m1", "m1", "mosquitto", "127.0.0.2", 1883)
TOPIC = TopicSpec("m1", "a/b", "urn:x:t", qos=1)
GOOD = ValidationReport(True, (), "test", (), ())
BAD = ValidationReport(False, (ValidationResult("Violation", "urn:x:m1", "pk:port", "70000",
                                                "pk:port must be 1 to 65535", "pks:x", "sh:x"),),
                       "test", (), ())


def test_plant_files_are_files_and_every_ttl_in_folders(tmp_path: Path) -> None:
    plant, folder = tmp_path / "plant.ttl", tmp_path / "found"
    (folder / "deep").mkdir(parents=True)
    for name in ("b.ttl", "a.ttl", "deep/c.ttl", ".hidden.ttl", "notes.txt", "x.ttl.tmp"):
        (folder / name).write_text("")
    (folder / ".partial").mkdir()
    (folder / ".partial" / "d.ttl").write_text("")
    plant.write_text("")
    assert plant_files([plant, folder]) == [plant, folder / "a.ttl", folder / "b.ttl",
                                            folder / "deep" / "c.ttl"]


def test_a_change_is_a_change_of_content_not_of_mtime(tmp_path: Path) -> None:
    path = tmp_path / "p.ttl"
    path.write_text("one")
    first = content_digest([path])
    os.utime(path, (1, 1))
    assert content_digest([path]) == first
    stat = path.stat()
    path.write_text("two")
    os.utime(path, ns=(stat.st_atime_ns, stat.st_mtime_ns))  # same mtime, other bytes
    assert content_digest([path]) != first
    assert content_digest([tmp_path / "gone.ttl"]) != content_digest([path])


class Stub:
    """The pipeline: the desired state it returns, a report, calls counted; agents: a FakeFleet."""

    def __init__(self, fleet: FakeFleet, owner: str | None = OWNER) -> None:
        self.fleet = fleet
        self.desired = DesiredState(brokers=(BROKER,), topics=(TOPIC,), owner=owner)
        self.report = GOOD
        self.calls = 0

    def __call__(self, files: list[Path], directory: Any, *, owner: str | None, prune: bool) -> Pipeline:
        self.calls += 1
        result = Pipeline(None, self.report)
        if not self.report.conforms:
            return result
        result.desired = self.desired if owner is None else DesiredState(
            self.desired.brokers, self.desired.topics, self.desired.bridges, owner)
        result.observed = observe(directory, {"127.0.0.2"})
        result.plan = make_plan(result.desired, result.observed, prune=prune)
        return result


@pytest.fixture
def plant(tmp_path: Path) -> Path:
    path = tmp_path / "plant.ttl"
    path.write_text("# version 1\n")
    return path


def test_a_run_applies_with_the_owner_and_a_second_finds_nothing(plant: Path) -> None:
    fleet = FakeFleet()
    stub = Stub(fleet)
    loop = ReconcileLoop([plant], fleet.directory(), pipeline=stub)
    first = loop.run_once()
    assert first.applied and first.converged and first.error is None
    assert first.summary == {"create": 2, "update": 0, "replace": 0, "delete": 0}
    assert fleet.brokers["m1"].owner == OWNER
    second = loop.run_once()
    assert not second.applied and second.converged and stub.calls == 1  # same content: no re-read


def test_an_invalid_plant_is_never_applied_and_the_last_valid_stays(plant: Path) -> None:
    fleet = FakeFleet()
    stub = Stub(fleet)
    loop = ReconcileLoop([plant], fleet.directory(), pipeline=stub)
    loop.run_once()
    digest = loop.status.digest
    stub.report = BAD
    plant.write_text("# version 2, broken\n")
    del fleet.brokers["m1"]  # drift while the files are broken
    run = loop.run_once()
    status = loop.status
    assert status.invalid is not None and "pk:port must be 1 to 65535" in status.invalid
    assert status.digest == digest and loop.desired is not None
    assert run.applied and fleet.brokers["m1"].owner == OWNER  # put back with the last valid plant


def test_a_plant_without_owner_is_refused(plant: Path) -> None:
    fleet = FakeFleet()
    loop = ReconcileLoop([plant], fleet.directory(), pipeline=Stub(fleet, owner=None))
    run = loop.run_once()
    assert not run.applied and "no owner" in (run.error or "")
    assert fleet.verbs() == [("list_brokers", ""), ("list_bridges", "")]  # asked, never changed


def test_never_two_applies_at_once(plant: Path) -> None:
    fleet = FakeFleet()
    inside, most, gate = [0], [0], threading.Lock()

    def slow_apply(*args: Any, **kwargs: Any) -> Any:
        with gate:
            inside[0] += 1
            most[0] = max(most[0], inside[0])
        try:
            threading.Event().wait(0.2)  # hold the apply open, so the other runs would overlap
            return apply(*args, **kwargs)
        finally:
            with gate:
                inside[0] -= 1

    loop = ReconcileLoop([plant], fleet.directory(), pipeline=Stub(fleet), apply_fn=slow_apply)
    threads = [threading.Thread(target=loop.run_once) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10)
    assert most[0] == 1 and loop.status.runs == 3


def test_a_burst_of_pokes_is_one_run(plant: Path) -> None:
    fleet = FakeFleet()
    stub = Stub(fleet)
    loop = ReconcileLoop([plant], fleet.directory(), pipeline=stub, interval=3600, debounce=0.1)
    loop.start()
    try:
        process.wait_until(lambda: loop.status.runs >= 1, 10.0, 0.01, what="the first run")
        plant.write_text("# version 2\n")
        for _ in range(5):
            loop.poke()
        process.wait_until(lambda: loop.status.runs >= 2, 10.0, 0.01, what="the poke's run")
    finally:
        loop.stop()
    assert loop.status.runs == 2 and loop.last_run is not None
    assert loop.last_run.trigger == "poke" and stub.calls == 2
