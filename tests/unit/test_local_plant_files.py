"""engine.demo.local_plant's plant-file edits and process scan (no agent, no broker)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import rdflib

from engine import process
from engine.errors import EngineError
from engine.demo.local_plant import copy_on_free_ports, processes_under, set_port
from kg.namespaces import PK
from kg.resources import examples_dir


def ports_of(path: Path) -> dict[str, int]:
    g = rdflib.Graph().parse(str(path), format="turtle")
    return {str(g.value(b, PK.id)): int(p) for b, p in g.subject_objects(PK.port)}


def test_copy_moves_every_broker_to_a_distinct_port_and_keeps_the_rest(tmp_path: Path) -> None:
    source = examples_dir() / "multi-machine.ttl"
    moved = copy_on_free_ports(source, tmp_path / "plant.ttl")
    assert set(moved) == {"mosquitto-a", "mosquitto-b", "kafka"}
    assert ports_of(tmp_path / "plant.ttl") == moved
    assert len(set(moved.values())) == 3
    assert not {1883, 9092} & set(moved.values())
    before = rdflib.Graph().parse(str(source), format="turtle")
    after = rdflib.Graph().parse(str(tmp_path / "plant.ttl"), format="turtle")
    assert len(before) == len(after)
    assert set(before.triples((None, PK.hasTopic, None))) == set(after.triples((None, PK.hasTopic, None)))


def test_set_port_changes_one_broker(tmp_path: Path) -> None:
    plant = tmp_path / "plant.ttl"
    moved = copy_on_free_ports(examples_dir() / "robot-cell.ttl", plant)
    set_port(plant, "mosquitto", 4242)
    assert ports_of(plant) == {**moved, "mosquitto": 4242}


def test_set_port_of_an_unknown_broker_says_so(tmp_path: Path) -> None:
    plant = tmp_path / "plant.ttl"
    copy_on_free_ports(examples_dir() / "robot-cell.ttl", plant)
    with pytest.raises(EngineError, match="0 brokers with pk:id 'nope'"):
        set_port(plant, "nope", 4242)


def test_processes_under_finds_a_live_process_naming_the_folder(tmp_path: Path) -> None:
    marker = tmp_path / "state"
    marker.mkdir()
    child = process.spawn([sys.executable, "-c", "import sys, time; time.sleep(60)", str(marker)],
                          log_dir=tmp_path, name="sleeper")
    try:
        # the child names the folder once it has exec'd Python, a moment after spawn returns
        process.wait_until(lambda: any(str(child.pid) == line.split(":")[0] for line in processes_under(tmp_path)),
                           30.0, what="the sleeper to show under its folder", child=child)
    finally:
        process.stop(child, grace=5)
    assert processes_under(tmp_path) == []
