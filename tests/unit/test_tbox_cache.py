"""The fast reasoner keeps its reading of the TBox per process (engine.reasoning.tbox_cache): the
same inferences with and without it, the TBox read again when a plant file adds an axiom or an
ontology file changes, the plant's vocabulary checked every time."""

from __future__ import annotations

from pathlib import Path

import pyoxigraph as ox
import pytest

from engine.reasoning import reason as reason_module
from engine.reasoning import tbox_cache
from engine.reasoning.reason import reason
from engine.reasoning.rules_errors import UnsupportedConstructError
from kg import resources
from kg.load import load_plant
from kg.namespaces import GRAPH_INFERRED

PLANT = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .
@prefix : <https://example.org/cache#> .
:mqtt a pk:Broker ; pk:id "mqtt" ; pk:name "m" ; pk:brokerType "mosquitto" ; pk:ip "127.0.0.2" ;
    pk:port 1883 ; pk:hasTopic :t .
:kafka a pk:Broker ; pk:id "kafka" ; pk:name "k" ; pk:brokerType "kafka" ; pk:ip "127.0.0.3" ;
    pk:port 9092 ; pk:hasTopic :t .
:t a pk:Topic ; pk:id "t" ; pk:name "cell.t" .
:r a pk:Resource ; pk:id "r" ; pk:name "robot" ; pk:sendsTo :mqtt ; pk:publishes :t .
:s a pk:Resource ; pk:id "s" ; pk:name "historian" ; pk:sendsTo :kafka ; pk:subscribes :t .
"""


def inferred(path: Path, *, ontology: Path | None = None) -> set[str]:
    plant = load_plant([path], ontology=ontology)
    reason(plant, engine="fast")
    return {str(q) for q in plant.store.quads_for_pattern(None, None, None, ox.NamedNode(GRAPH_INFERRED))
            if "inferred by plantkg" not in str(q.object)}


@pytest.fixture
def reads(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Counts the TBox reads (cache misses)."""
    tbox_cache.clear()
    count: list[int] = []
    real = tbox_cache.read_tbox

    def counting(*args, **kwargs):  # type: ignore[no-untyped-def]
        count.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(tbox_cache, "read_tbox", counting)
    yield count
    tbox_cache.clear()


def test_the_tbox_is_read_once_and_the_inferences_are_the_same(tmp_path: Path, reads: list[int]) -> None:
    plant = tmp_path / "plant.ttl"
    plant.write_text(PLANT)
    first = inferred(plant)
    assert any("requiresBridge" in q for q in first), sorted(first)[:5]
    plant.write_text(PLANT.replace("1883", "1884"))  # another plant, the same TBox
    second = inferred(plant)
    assert second == first and len(reads) == 1


def test_a_plant_adding_an_axiom_is_read_whole(tmp_path: Path, reads: list[int]) -> None:
    plant = tmp_path / "plant.ttl"
    plant.write_text(PLANT)
    inferred(plant)
    plant.write_text(PLANT + ":Gateway rdfs:subClassOf pk:Resource .\n:g a :Gateway ; pk:id \"g\" ; pk:name \"g\" .\n")
    extra = inferred(plant)
    assert len(reads) == 2
    assert "<https://example.org/cache#g> <http://www.w3.org/1999/02/22-rdf-syntax-ns#type> " \
           "<https://w3id.org/plantkg/ontology#Resource> <" + GRAPH_INFERRED + ">" in extra


def test_a_changed_ontology_file_is_read_again(tmp_path: Path, reads: list[int]) -> None:
    ontology = tmp_path / "onto.ttl"
    ontology.write_bytes(b"".join(p.read_bytes() for p in resources.tbox_files()[:1]))
    plant = tmp_path / "plant.ttl"
    plant.write_text(PLANT)
    inferred(plant, ontology=ontology)
    inferred(plant, ontology=ontology)
    assert len(reads) == 1
    ontology.write_bytes(ontology.read_bytes() + b"\n# edited\n")
    inferred(plant, ontology=ontology)
    assert len(reads) == 2


def test_the_plants_vocabulary_is_checked_on_a_cache_hit(tmp_path: Path, reads: list[int]) -> None:
    plant = tmp_path / "plant.ttl"
    plant.write_text(PLANT)
    inferred(plant)
    plant.write_text(PLANT + "[] a pk:Resource ; pk:id \"anon\" ; pk:name \"anon\" .\n")
    loaded = load_plant([plant])
    with pytest.raises(UnsupportedConstructError, match="anonymous individual"):
        reason_module._run_fast(loaded)
    assert len(reads) == 1
