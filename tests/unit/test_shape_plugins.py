"""The shapes take the allowed pk:brokerType values from the registered drivers, and packages add
shapes of their own, both through entry points (kg.shape_plugins). Entry points are faked here:
the test must not depend on which plugin packages this machine has installed."""

from __future__ import annotations

from collections.abc import Iterator
from importlib.metadata import EntryPoint
from pathlib import Path

import pytest
from rdflib import Graph, Literal
from rdflib.collection import Collection

from kg import shape_plugins
from kg.errors import ShapesError
from kg.load import load_plant
from kg.namespaces import PKS, SH
from kg.validate import load_default_shapes, validate

ROOT = Path(__file__).resolve().parents[2]
#: The shape cases' base plant with its Kafka broker's type changed to "activemq" (no driver).
UNKNOWN_TYPE_PLANT = ROOT / "tests" / "cases" / "shapes" / "broker-type-unknown" / "plant.ttl"
BUILT_IN = ("kafka", "mosquitto", "ngsi-v2")


def fake_entry_points(drivers: tuple[str, ...], shapes: dict[str, str] | None = None):
    eps = [EntryPoint(k, f"somewhere.{k}:Driver", shape_plugins.DRIVERS_GROUP) for k in drivers]
    eps += [EntryPoint(n, v, shape_plugins.SHAPES_GROUP) for n, v in (shapes or {}).items()]

    def entry_points(*, group: str) -> list[EntryPoint]:
        return [ep for ep in eps if ep.group == group]
    return entry_points


@pytest.fixture
def installed(monkeypatch: pytest.MonkeyPatch) -> Iterator:
    """Call with the driver names (and shapes entry points) that count as installed."""
    def install(drivers: tuple[str, ...], shapes: dict[str, str] | None = None) -> None:
        monkeypatch.setattr(shape_plugins, "entry_points", fake_entry_points(drivers, shapes))
        shape_plugins.forget_entry_points()
    yield install
    shape_plugins.forget_entry_points()  # empty cache: the next read, unpatched, sees the real ones


def broker_type_values(graph: Graph) -> list[str]:
    head = graph.value(PKS["Broker-brokerTypeValue"], SH["in"])
    return sorted(str(v) for v in Collection(graph, head))


def message_of(graph: Graph) -> str:
    return str(graph.value(PKS["Broker-brokerTypeValue"], SH.message))


def test_the_built_in_drivers_leave_the_shapes_as_written(installed) -> None:
    installed(BUILT_IN)
    report = validate(load_plant([UNKNOWN_TYPE_PLANT]))
    [result] = report.violations
    assert result.value == "activemq" and result.component.endswith("InConstraintComponent")
    assert result.message.startswith("Unknown pk:brokerType: plantkg has drivers for mosquitto, kafka")


def test_a_registered_driver_makes_its_type_valid(installed) -> None:
    installed((*BUILT_IN, "activemq"))
    shapes = load_default_shapes()
    assert broker_type_values(shapes.graph) == ["activemq", *BUILT_IN]
    for engine in ("oxigraph", "pyshacl"):
        report = validate(load_plant([UNKNOWN_TYPE_PLANT]), shapes, engine=engine)  # type: ignore[arg-type]
        assert report.conforms, [r.message for r in report.results]


def test_an_unknown_type_names_the_installed_drivers(installed) -> None:
    installed((*BUILT_IN, "nats"))
    report = validate(load_plant([UNKNOWN_TYPE_PLANT]))
    [result] = report.violations
    assert result.value == "activemq"
    assert "the installed drivers are kafka, mosquitto, nats and ngsi-v2" in result.message


def test_no_driver_at_all_keeps_the_written_list() -> None:
    graph = load_default_shapes().graph
    before = broker_type_values(graph), message_of(graph)
    copy = Graph()
    for triple in graph:
        copy.add(triple)
    shape_plugins.with_broker_types(copy, [])
    assert (broker_type_values(copy), message_of(copy)) == before


def test_rewriting_replaces_the_list_and_message_once() -> None:
    graph = Graph()
    for triple in load_default_shapes().graph:
        graph.add(triple)
    shape_plugins.with_broker_types(graph, ["b", "a", "a"])
    assert broker_type_values(graph) == ["a", "b"]
    assert list(graph.objects(PKS["Broker-brokerTypeValue"], SH.message)) == [
        Literal(shape_plugins.unknown_type_message(["a", "b"]))]
    assert len(list(graph.objects(PKS["Broker-brokerTypeValue"], SH["in"]))) == 1


def test_a_package_adds_its_shapes(installed, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    package = tmp_path / "pk_plugin_shapes"
    package.mkdir()
    (package / "__init__.py").write_text("")
    # Every broker needs a pk:description: a shape the core does not have.
    (package / "extra.ttl").write_text("""
@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix sh: <http://www.w3.org/ns/shacl#> .
<urn:test:Broker-description> a sh:NodeShape ; sh:targetClass pk:Broker ;
    sh:property [ sh:path pk:description ; sh:minCount 1 ; sh:message "needs a description" ] .
""")
    monkeypatch.syspath_prepend(str(tmp_path))
    installed((*BUILT_IN, "activemq"), {"extra": "pk_plugin_shapes"})
    assert shape_plugins.plugin_shapes_files() == [package / "extra.ttl"]
    shapes = load_default_shapes()
    assert package / "extra.ttl" in shapes.files
    report = validate(load_plant([UNKNOWN_TYPE_PLANT]), shapes)
    assert {r.message for r in report.violations} == {"needs a description"}
    assert {r.focus.rsplit("#", 1)[-1] for r in report.violations} == {"mqtt2", "kafka1"}


@pytest.mark.parametrize(("value", "problem"), [
    ("no_such_package_for_plantkg", "cannot import the package"),
    ("pk_empty_plugin", "no .ttl file"),
    ("pk_empty_plugin:attr", "names an attribute"),
])
def test_a_broken_shapes_entry_point_is_a_clear_error(installed, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                      value: str, problem: str) -> None:
    (tmp_path / "pk_empty_plugin").mkdir()
    (tmp_path / "pk_empty_plugin" / "__init__.py").write_text("")
    monkeypatch.syspath_prepend(str(tmp_path))
    installed(BUILT_IN, {"broken": value})
    with pytest.raises(ShapesError, match=problem) as info:
        shape_plugins.plugin_shapes_files()
    assert "'broken'" in str(info.value) and "plantkg.shapes" in str(info.value)
