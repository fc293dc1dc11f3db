"""Which plant owns what a plant deploys (engine.owner): pk:plantName, else the plant's
owl:Ontology IRI, else none; ambiguity is an error; an explicit owner wins (engine.pipeline)."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.owner import OwnerError, plant_owner
from engine.pipeline import run_pipeline
from kg.load import load_plant

PREFIXES = """\
@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix owl: <http://www.w3.org/2002/07/owl#> .
@prefix : <http://example.org/p#> .
"""
BROKER = """\
:mqtt a pk:Broker ; pk:id "mqtt" ; pk:name "m" ; pk:brokerType "mosquitto" ; pk:ip "127.0.0.2" ;
    pk:port 1883 ; pk:hasTopic :pose .
:pose a pk:Topic ; pk:id "pose" ; pk:name "robot.pose" ; pk:qos 1 .
"""


def write(tmp_path: Path, name: str, header: str, body: str = "") -> Path:
    path = tmp_path / name
    path.write_text(PREFIXES + header + body)
    return path


@pytest.mark.parametrize(("headers", "owner"), [
    (['<http://example.org/p> a owl:Ontology .\n'], "http://example.org/p"),
    (['<http://example.org/p> a owl:Ontology ; pk:plantName "line-3" .\n'], "line-3"),
    (['<http://example.org/p> a owl:Ontology ; pk:plantName "line-3" .\n',
      '<http://example.org/q> a owl:Ontology .\n'], "line-3"),
    ([""], None),
    (['<https://w3id.org/plantkg/ontology/x> a owl:Ontology .\n'], None),  # plantkg's own: not a plant
])
def test_the_owner(tmp_path: Path, headers: list[str], owner: str | None) -> None:
    files = [write(tmp_path, f"f{i}.ttl", h, BROKER if i == 0 else "") for i, h in enumerate(headers)]
    assert plant_owner(load_plant(files)) == owner


@pytest.mark.parametrize(("headers", "match"), [
    (['<http://example.org/p> a owl:Ontology .\n', '<http://example.org/q> a owl:Ontology .\n'],
     "several ontologies"),
    (['<http://example.org/p> a owl:Ontology ; pk:plantName "a" , "b" .\n'], "2 names"),
    (['<http://example.org/p> a owl:Ontology ; pk:plantName "line 3" .\n'], "not a usable owner"),
])
def test_an_unclear_owner_is_an_error(tmp_path: Path, headers: list[str], match: str) -> None:
    files = [write(tmp_path, f"f{i}.ttl", h, BROKER if i == 0 else "") for i, h in enumerate(headers)]
    with pytest.raises(OwnerError, match=match):
        plant_owner(load_plant(files))


def test_the_pipeline_carries_the_owner_and_an_explicit_one_wins(tmp_path: Path) -> None:
    one = write(tmp_path, "a.ttl", '<http://example.org/p> a owl:Ontology .\n', BROKER)
    assert run_pipeline([one], observe=False).desired.owner == "http://example.org/p"  # type: ignore[union-attr]
    two = write(tmp_path, "b.ttl", '<http://example.org/q> a owl:Ontology .\n')
    with pytest.raises(OwnerError):
        run_pipeline([one, two], observe=False)
    assert run_pipeline([one, two], observe=False, owner="cell-9").desired.owner == "cell-9"  # type: ignore[union-attr]
