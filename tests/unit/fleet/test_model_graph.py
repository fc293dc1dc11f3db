"""fleet.model.graph: a vehicle's description as Turtle, and what plantkg makes of it.

The whole chain without a broker: the example plant (ontology/examples/agv-fleet.ttl) and the same
plant with its hand-written vehicles replaced by agv_turtle's output for the simulator's factsheet
and the contract's paper description are validated, reasoned over and derived
(engine.pipeline.run_pipeline(..., observe=False)); the derived DesiredState must show the
Mosquitto broker carrying every channel, the context broker carrying the channels the fleet view
reads as the vehicle's one entity, and one mqtt-ngsi bridge carrying exactly those. The expected
channels are written out here from the fleet contract, not computed from fleet.model's tables.
"""

from __future__ import annotations

import dataclasses
import shutil
import time
from pathlib import Path

import pyoxigraph as ox
import pytest
from rdflib import Graph, URIRef
from rdflib.namespace import RDF

from engine.model import BridgeDirection, BridgeMechanism, DesiredState
from engine.pipeline import run_pipeline
from fleet.model import graph as graph_module
from fleet.model.binding import FleetBinding, fleet_binding
from fleet.model.description import AgvDescription, from_factsheet, from_paper_description
from fleet.model.errors import DescriptionError
from fleet.model.graph import CHANNELS, agv_id, agv_iri, agv_turtle
from kg.load import load_plant
from kg.namespaces import FLEET, PK
from kg.validate import validate
from tests.unit.fleet.test_model_description import paper_description, sim_factsheet

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "ontology" / "examples" / "agv-fleet.ttl"

VDA_CHANNELS = {"order": (0, False), "instantActions": (0, False), "state": (0, False),
                "visualization": (0, False), "connection": (1, True), "factsheet": (0, False)}
VDA_ENTITY = {"state", "connection", "factsheet"}
PAPER_CHANNELS = {"action_channel": (1, False), "motion_channel": (1, False), "movement_channel": (0, False),
                  "status_channel": (1, True), "description_channel": (1, True)}
PAPER_ENTITY = {"status_channel", "movement_channel", "description_channel"}
PAPER_COMMANDS = {"action_channel", "motion_channel"}


@dataclasses.dataclass(frozen=True)
class Vehicle:
    serial: str
    manufacturer: str
    interface: str


def expected_state(vehicles: list[Vehicle]) -> tuple[dict, dict, dict]:
    """(mqtt topics name -> (qos, retain), context topics name -> (entity id, type), routes name -> direction)."""
    mqtt, context, routes = {}, {}, {}
    for v in vehicles:
        if v.interface == "vda5050":
            for channel, rule in VDA_CHANNELS.items():
                name = f"uagv/v2/{v.manufacturer}/{v.serial}/{channel}"
                mqtt[name] = rule
                if channel in VDA_ENTITY:
                    context[name] = (f"urn:ngsi-ld:AGV:{v.serial}", "AGV")
        else:
            for channel, rule in PAPER_CHANNELS.items():
                name = f"{v.serial}/{channel}"
                mqtt[name] = rule
                if channel in PAPER_ENTITY:
                    context[name] = (f"urn:ngsi-ld:AGV:{v.serial}", "AGV")
                elif channel in PAPER_COMMANDS:
                    context[name] = (f"urn:ngsi-ld:Thing:{v.serial}:{channel}", "Thing")
    return mqtt, context, {name: None for name in context}


def check_fleet_state(desired: DesiredState, vehicles: list[Vehicle], mqtt_id: str, context_id: str) -> None:
    mqtt, context, routes = expected_state(vehicles)
    on_mqtt = {t.name: (t.qos, t.retain) for t in desired.topics if t.broker_id == mqtt_id}
    on_context = {t.name: (t.entity_id, t.entity_type) for t in desired.topics if t.broker_id == context_id}
    assert on_mqtt == mqtt
    assert on_context == context
    [bridge] = desired.bridges
    assert bridge.mechanism is BridgeMechanism.NGSI
    assert (bridge.local.id, bridge.remote.id) == (mqtt_id, context_id)
    assert {r.topic: (r.entity_id, r.entity_type) for r in bridge.routes} == context
    for route in bridge.routes:  # the vehicle's channels reach the entity; commands come back, and only they
        command = route.topic.rsplit("/", 1)[1] in PAPER_COMMANDS
        assert route.direction is (BridgeDirection.IN if command else BridgeDirection.OUT), route
        assert route.qos == mqtt[route.topic][0]
    assert {b.id: b.kind for b in desired.brokers} == {mqtt_id: "mosquitto", context_id: "ngsi-v2"}


def test_the_example_plant_derives_the_fleets_topics_and_one_bridge() -> None:
    result = run_pipeline([EXAMPLE], observe=False)
    assert result.valid, [r.message for r in result.report.results]
    check_fleet_state(result.desired, [Vehicle("sim-0001", "plantkg-sim", "vda5050"),
                                       Vehicle("cart-1", "plantkg-sim", "paper-channels")],
                      "fleet-mqtt", "fleet-context")


# --- the example without its hand-written vehicles, plus discovered ones --------------------------

def plant_without_vehicles(tmp_path: Path) -> Path:
    """agv-fleet.ttl minus its AGVs and everything only they use (topics, properties)."""
    g = Graph().parse(EXAMPLE, format="turtle")
    agvs = set(g.subjects(PK.isType, FLEET.agv))
    assert len(agvs) == 2
    owned = set(agvs)
    for agv in agvs:
        for p in (PK.publishes, PK.subscribes, PK.hasProperty):
            owned |= set(g.objects(agv, p))
    for s, p, o in list(g):
        if s in owned or o in owned:
            g.remove((s, p, o))
    out = tmp_path / "plant.ttl"
    g.serialize(out, format="turtle")
    return out


def discovered(tmp_path: Path, binding: FleetBinding, descs: list[AgvDescription], **kw: object) -> list[Path]:
    paths = []
    for i, desc in enumerate(descs):
        path = tmp_path / f"discovered-{i}.ttl"
        path.write_text(agv_turtle(desc, binding, **kw), encoding="utf-8")  # type: ignore[arg-type]
        paths.append(path)
    return paths


def test_discovered_vehicles_validate_and_derive_like_hand_written_ones(tmp_path: Path) -> None:
    base = plant_without_vehicles(tmp_path)
    binding = fleet_binding([base])
    vda = from_factsheet("plantkg-sim", "sim-0042", sim_factsheet(serial="sim-0042"))
    paper = from_paper_description(paper_description("agv-7"))
    files = [base, *discovered(tmp_path, binding, [vda, paper])]
    for engine in ("oxigraph", "pyshacl"):
        report = validate(load_plant(files), engine=engine)  # type: ignore[arg-type]
        assert report.conforms, [(r.focus, r.message) for r in report.results]
        assert report.results == ()
    result = run_pipeline(files, observe=False)
    assert result.valid
    check_fleet_state(result.desired, [Vehicle("sim-0042", "plantkg-sim", "vda5050"),
                                       Vehicle("agv-7", "plantkg-sim", "paper-channels")],
                      "fleet-mqtt", "fleet-context")


def test_the_example_with_its_own_vehicles_and_discovered_ones_together(tmp_path: Path) -> None:
    """Discovered vehicles share the plant's skills (same IRI, same triples): no duplicate id."""
    binding = fleet_binding([EXAMPLE])
    descs = [from_factsheet("acme", f"a-{i}", sim_factsheet("acme", f"a-{i}")) for i in range(3)]
    descs.append(from_paper_description(paper_description("agv-7")))
    files = [EXAMPLE, *discovered(tmp_path, binding, descs, connection_state="OFFLINE", pinned=True)]
    result = run_pipeline(files, observe=False)
    assert result.valid, [(r.focus, r.message) for r in result.report.results]
    vehicles = [Vehicle("sim-0001", "plantkg-sim", "vda5050"), Vehicle("cart-1", "plantkg-sim", "paper-channels"),
                *(Vehicle(f"a-{i}", "acme", "vda5050") for i in range(3)), Vehicle("agv-7", "plantkg-sim", "paper-channels")]
    check_fleet_state(result.desired, vehicles, "fleet-mqtt", "fleet-context")
    rows = result.plant.store.query(  # SPARQL sees a discovered vehicle with its skills
        "SELECT ?skill WHERE { ?agv fleet:serialNumber 'a-1' ; fleet:discovered true ; "
        "fleet:connectionState 'OFFLINE' ; fleet:pinned true ; pk:executes/pk:id ?skill }",
        prefixes={"pk": str(PK), "fleet": str(FLEET)}, use_default_graph_as_union=True)
    assert {r["skill"].value for r in rows} >= {"move", "pick", "drop", "startCharging"}


def test_a_serial_with_colons_gets_an_id_of_its_own(tmp_path: Path) -> None:
    base = plant_without_vehicles(tmp_path)
    binding = fleet_binding([base])
    colon = from_factsheet("KIT", "KIT:0001", sim_factsheet("KIT", "KIT:0001"))
    underscore = from_factsheet("KIT", "KIT_0001", sim_factsheet("KIT", "KIT_0001"))
    assert agv_id("KIT_0001") == "KIT_0001" and agv_id("KIT:0001").startswith("KIT_0001-")
    assert agv_iri(colon, binding) != agv_iri(underscore, binding)
    result = run_pipeline([base, *discovered(tmp_path, binding, [colon, underscore])], observe=False)
    assert result.valid, [(r.focus, r.message) for r in result.report.results]
    check_fleet_state(result.desired, [Vehicle("KIT:0001", "KIT", "vda5050"), Vehicle("KIT_0001", "KIT", "vda5050")],
                      "fleet-mqtt", "fleet-context")


def test_the_same_vehicle_twice_is_refused_by_the_shapes(tmp_path: Path) -> None:
    base = plant_without_vehicles(tmp_path)
    binding = fleet_binding([base])
    one = from_factsheet("acme", "a-1", sim_factsheet("acme", "a-1"))
    other = from_factsheet("other", "a-1", sim_factsheet("other", "a-1"))
    report = validate(load_plant([base, *discovered(tmp_path, binding, [one, other])]))
    assert not report.conforms  # one serial, one IRI: two manufacturers on one individual
    assert {(r.shape.rsplit("#", 1)[-1], r.value) for r in report.violations} >= {
        ("FleetResource-manufacturer", None)}
    named = one.__class__(**{**dataclasses.asdict(other), "skills": other.skills, "properties": other.properties})
    text = agv_turtle(named, binding).replace("agv-a-1", "agv-a-1-copy")  # the same serial under another IRI
    (tmp_path / "copy.ttl").write_text(text, encoding="utf-8")
    report = validate(load_plant([base, *discovered(tmp_path, binding, [one]), tmp_path / "copy.ttl"]))
    assert {(r.shape.rsplit("#", 1)[-1], r.value) for r in report.violations} == {("Agv-uniqueSerial", "a-1")}


# --- the document itself ---------------------------------------------------------------------------

@pytest.fixture(scope="module")
def binding() -> FleetBinding:
    return fleet_binding([EXAMPLE])


def test_a_whole_turtle_document_in_both_parsers(binding: FleetBinding) -> None:
    desc = from_paper_description(paper_description())
    text = agv_turtle(desc, binding)
    assert text == agv_turtle(desc, binding)  # the same vehicle, the same bytes
    g = Graph().parse(data=text, format="turtle")
    store = ox.Store()
    store.load(text.encode(), format=ox.RdfFormat.TURTLE)
    assert len(store) == len(g) > 50
    agv = URIRef(agv_iri(desc, binding))
    assert (agv, RDF.type, PK.Resource) in g and (agv, PK.isType, FLEET.agv) in g
    assert str(g.value(agv, FLEET.serialNumber)) == "agv-7"
    assert g.value(agv, FLEET.discovered).toPython() is True


def test_the_resource_types_it_uses_are_the_modules(binding: FleetBinding) -> None:
    module = Graph().parse(ROOT / "ontology" / "plantkg-fleet.ttl", format="turtle")
    for t in (FLEET.agv, FLEET["fleet-manager"], FLEET["fleet-view"]):
        assert (t, RDF.type, PK.ResourceType) in module
    g = Graph().parse(data=agv_turtle(from_paper_description(paper_description()), binding), format="turtle")
    used = {o for o in g.objects(None, PK.isType)}
    assert used == {FLEET.agv}


def test_channel_rules_agree_with_the_interface_implementations() -> None:
    from fleet.vda5050 import topics

    assert {c.name: (c.qos, c.retain) for c in CHANNELS["vda5050"]} == VDA_CHANNELS
    for c in CHANNELS["vda5050"]:
        rule = topics.rule(c.name)
        assert (rule.qos, rule.retain) == (c.qos, c.retain)
        assert c.vehicle_publishes is not topics.Subtopic(c.name).from_master
    assert {c.name: (c.qos, c.retain) for c in CHANNELS["paper-channels"]} == PAPER_CHANNELS
    channels = pytest.importorskip("fleet.paper.channels")
    for c in CHANNELS["paper-channels"]:
        rule = channels.rule(c.name)
        assert (rule.qos, rule.retain) == (c.qos, c.retain), c.name


class _NoGraph:
    def __init__(self, *args: object, **kwargs: object) -> None:
        raise AssertionError("a graph was built for a refused description")


BAD_CALLS = [
    ("serial with a slash", {"serial": "a/b"}, {}, "serial"),
    ("serial of 65 characters", {"serial": "s" * 65}, {}, "serial"),
    ("empty serial", {"serial": ""}, {}, "serial"),
    ("serial not a string", {"serial": 7}, {}, "serial"),
    ("manufacturer with #", {"manufacturer": "a#"}, {}, "manufacturer"),
    ("unknown interface", {"interface": "opc-ua"}, {}, "interface"),
    ("name with a newline", {"name": "AGV\n7"}, {}, "name"),
    ("connection state", {}, {"connection_state": "online"}, "connection_state"),
    ("pinned not a boolean", {}, {"pinned": "yes"}, "pinned"),
]


@pytest.mark.parametrize(("label", "change", "kw", "field"), BAD_CALLS, ids=[b[0] for b in BAD_CALLS])
def test_a_bad_description_is_refused_before_any_triple(monkeypatch: pytest.MonkeyPatch, binding: FleetBinding,
                                                        label: str, change: dict, kw: dict, field: str) -> None:
    desc = dataclasses.replace(from_paper_description(paper_description()), **change)
    monkeypatch.setattr(graph_module, "Graph", _NoGraph)
    with pytest.raises(DescriptionError) as err:
        agv_turtle(desc, binding, **kw)
    assert err.value.field == field


# --- both reasoning engines conclude the same facts on discovered vehicles ----------------------------

@pytest.mark.skipif(shutil.which("java") is None, reason="HermiT needs Java")
def test_both_engines_agree_on_discovered_vehicles(tmp_path: Path) -> None:
    from engine.reasoning.reason import reason
    from kg.namespaces import GRAPH_INFERRED

    base = plant_without_vehicles(tmp_path)
    binding = fleet_binding([base])
    descs = [from_factsheet("acme", "a-1", sim_factsheet("acme", "a-1")),
             from_paper_description(paper_description("agv-7"))]
    files = [base, *discovered(tmp_path, binding, descs)]
    inferred = ox.NamedNode(GRAPH_INFERRED)
    facts = {}
    for engine in ("fast", "owlready2"):
        plant = load_plant(files)
        assert reason(plant, engine=engine).engine == engine  # type: ignore[arg-type]
        facts[engine] = {(q.subject.value, q.predicate.value, q.object.value)
                         for q in plant.store.quads_for_pattern(None, None, None, inferred) if q.subject != inferred}
    assert facts["fast"] == facts["owlready2"]
    view = "https://w3id.org/plantkg/examples/agv-fleet#fleet-view"
    subscribed = {o for s, p, o in facts["fast"] if s == view and p == str(PK.subscribes)}
    published = {o for s, p, o in facts["fast"] if s == view and p == str(PK.publishes)}
    assert len(subscribed) == 3 + 3 and len(published) == 2  # F3, F5-F7; F4


def test_fifty_discovered_vehicles_derive_one_bridge_with_all_their_routes(tmp_path: Path) -> None:
    """Fifty vehicles, one file each, as plug and play writes them (the time is printed, not
    asserted: benchmarks/bench_fleet_join.py measures it)."""
    base = plant_without_vehicles(tmp_path)
    binding = fleet_binding([base])
    descs = [from_factsheet("acme", f"v-{i}", sim_factsheet("acme", f"v-{i}")) for i in range(25)]
    descs += [from_paper_description(paper_description(f"p-{i}")) for i in range(25)]
    start = time.perf_counter()
    files = [base, *discovered(tmp_path, binding, descs)]
    result = run_pipeline(files, observe=False)
    print(f"\n50 discovered vehicles: {time.perf_counter() - start:.2f} s, {result.timings}")
    assert result.valid
    [bridge] = result.desired.bridges
    assert len(bridge.routes) == 25 * 3 + 25 * 5
