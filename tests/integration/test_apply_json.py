"""``plantkg apply|destroy --format json`` against a real agent and Mosquitto: one typed document
on stdout (numbers as numbers, booleans as booleans), with each change's outcome; nothing to do
gives the same shape with no outcomes; without --yes it refuses (exit 2) and starts nothing; an
invalid plant gives the violations report as JSON (exit 1)."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest

from engine import netutil
from engine.cli import main
from tests.integration.agents import AgentFleet, start_agents

pytestmark = pytest.mark.integration

HOST = "127.0.0.2"
PLANT = """\
@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <http://example.org/apply-json-test#> .
:t a pk:Topic ; pk:id "t" ; pk:name "line.t" ; pk:qos 1 .
:sensor a pk:Resource ; pk:id "sensor" ; pk:name "sensor" ; pk:sendsTo :m ; pk:publishes :t .
:m a pk:Broker ; pk:id "m" ; pk:name "m" ; pk:brokerType "mosquitto" ; pk:ip "{host}" ;
    pk:port {port} ; pk:hasTopic :t .
"""


@pytest.fixture(scope="module")
def fleet(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[AgentFleet, Path]]:
    tmp = tmp_path_factory.mktemp("apply-json")
    agents = start_agents([HOST], tmp)
    plant = tmp / "plant.ttl"
    plant.write_text(PLANT.format(host=HOST, port=netutil.free_port(HOST)), encoding="utf-8")
    try:
        yield agents, plant
    finally:
        agents.stop()


def run(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_apply_and_destroy_as_json(fleet: tuple[AgentFleet, Path], capsys: pytest.CaptureFixture[str]) -> None:
    agents, plant = fleet
    code, out, err = run(capsys, "apply", plant, "--agents", agents.agents_file, "--format", "json")
    assert code == 2 and "--yes" in err and out == ""
    assert agents.brokers() == {}                      # refused: nothing started

    code, out, err = run(capsys, "apply", plant, "--agents", agents.agents_file, "--format", "json", "--yes")
    assert code == 0, err
    doc = json.loads(out)
    assert (doc["verb"], doc["ok"], doc["converged"], doc["stillToDo"]) == ("apply", True, True, [])
    assert doc["counts"] == {"changed": len(doc["outcomes"]), "failed": 0, "skipped": 0}
    by_address = {o["address"]: o for o in doc["outcomes"]}
    assert by_address["broker.m"]["action"] == "create" and by_address["broker.m"]["status"] == "done"
    assert all(isinstance(o["seconds"], float) and isinstance(o["attempts"], int) and o["error"] is None
               for o in doc["outcomes"])
    assert doc["plan"]["applicable"] is True and isinstance(doc["seconds"], float)
    assert "m" in agents.brokers()

    code, out, _ = run(capsys, "apply", plant, "--agents", agents.agents_file, "--format", "json")
    again = json.loads(out)
    assert code == 0 and again["outcomes"] == [] and again["plan"]["empty"] is True

    code, out, err = run(capsys, "destroy", plant, "--agents", agents.agents_file, "--format", "json", "--yes")
    assert code == 0, err
    gone = json.loads(out)
    assert gone["verb"] == "destroy" and gone["ok"] is True
    assert {o["address"]: o["action"] for o in gone["outcomes"]}["broker.m"] == "delete"
    assert agents.brokers() == {}


def test_invalid_plant_is_a_json_report(fleet: tuple[AgentFleet, Path], capsys: pytest.CaptureFixture[str],
                                        tmp_path: Path) -> None:
    agents, plant = fleet
    bad = tmp_path / "bad.ttl"
    bad.write_text(plant.read_text().replace('pk:qos 1', 'pk:qos 7'), encoding="utf-8")
    code, out, _ = run(capsys, "apply", bad, "--agents", agents.agents_file, "--format", "json", "--yes")
    assert code == 1
    report = json.loads(out)
    assert report and "qos" in json.dumps(report)
