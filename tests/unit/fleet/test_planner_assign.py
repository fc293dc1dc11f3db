"""assign.rq: which vehicle takes a step, over the example plant with discovered vehicles and
the live states, as cases — each case on the whole plant and on the small assignment store
(assign.facts, what the planner runs it on), which must give the same rows. Prints the query's
latency on both (no timing assert)."""

from __future__ import annotations

import statistics
from pathlib import Path

import pytest

from fleet.model.binding import fleet_binding
from fleet.model.description import from_factsheet, from_paper_description
from fleet.model.graph import agv_turtle
import pyoxigraph as ox

from fleet.planner.assign import Live, Need, choose, facts
from fleet.planner.plantview import PlantView
from kg.load import PlantGraph, load_plant
from kg.namespaces import FLEET, PK
from tests.unit.fleet import discovery_data as d

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = ROOT / "ontology" / "examples" / "agv-fleet.ttl"
AGV = ox.NamedNode(str(FLEET.agv))


@pytest.fixture(scope="module")
def plant(tmp_path_factory: pytest.TempPathFactory) -> PlantGraph:
    folder = tmp_path_factory.mktemp("discovered")
    binding = fleet_binding([EXAMPLE])
    files = [EXAMPLE]
    for serial in ("a-1", "a-2", "a-3"):
        path = folder / f"t--{serial}.ttl"
        path.write_text(agv_turtle(from_factsheet("t", serial, d.factsheet("t", serial)), binding), encoding="utf-8")
        files.append(path)
    paper = folder / "paper.ttl"
    paper.write_text(agv_turtle(from_paper_description(d.paper_description("p-1")), binding), encoding="utf-8")
    return load_plant([*files, paper])


def live(serial: str, x: float, *, state: str = "ONLINE", idle: bool = True, battery: float | None = 80.0,
         manufacturer: str = "t") -> Live:
    return Live(serial, manufacturer, state, idle, x, 0.0, battery)


FLEET = [live("a-1", 9.0), live("a-2", 3.0), live("a-3", 5.0), live("p-1", 0.0, manufacturer="plantkg-sim")]
CASES = [  # (id, vehicles, need, expected first, expected candidates)
    ("nearest first", FLEET, Need("pick", "drop", 0.0, 0.0), "t/a-2", ["a-2", "a-3", "a-1"]),
    ("nearest to the other end", FLEET, Need("pick", "drop", 10.0, 0.0), "t/a-1", ["a-1", "a-3", "a-2"]),
    ("an offline and a busy vehicle are skipped",
     [live("a-1", 9.0), live("a-2", 3.0, state="CONNECTIONBROKEN"), live("a-3", 5.0, idle=False)],
     Need("pick", "drop", 0.0, 0.0), "t/a-1", ["a-1"]),
    ("low battery is skipped, no battery reported is not",
     [live("a-1", 9.0, battery=None), live("a-2", 3.0, battery=10.0)], Need("pick", "drop", 0.0, 0.0),
     "t/a-1", ["a-1"]),
    ("heavier than any vehicle's max load (120 kg)", FLEET, Need("pick", "drop", 0.0, 0.0, payload=150.0), None, []),
    ("a payload within the max load", FLEET, Need("pick", "drop", 0.0, 0.0, payload=120.0), "t/a-2",
     ["a-2", "a-3", "a-1"]),
    ("a skill nobody has", FLEET, Need("pick", "weld", 0.0, 0.0), None, []),
    ("the paper vehicle has load/unload, but only vda5050 is dispatched", FLEET,
     Need("load", "unload", 0.0, 0.0), None, []),
    ("the paper vehicle when paper-channels is asked", FLEET,
     Need("load", "unload", 0.0, 0.0, interface="paper-channels"), "plantkg-sim/p-1", ["p-1"]),
    ("a live vehicle the plant does not know is never chosen", [live("ghost", 0.0), live("a-3", 5.0)],
     Need("pick", "drop", 0.0, 0.0), "t/a-3", ["a-3"]),
]


@pytest.fixture(scope="module")
def small(plant: PlantGraph) -> ox.Store:
    return facts(plant.store)


@pytest.mark.parametrize("on", ["plant", "facts"])
@pytest.mark.parametrize(("vehicles", "need", "first", "candidates"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_assignment(plant: PlantGraph, small: ox.Store, on: str, vehicles: list[Live], need: Need,
                    first: str | None, candidates: list[str]) -> None:
    choice = choose(plant.store if on == "plant" else small, vehicles, need)
    assert choice.vehicle == first
    assert [r["serial"] for r in choice.rows] == candidates
    if first:
        assert choice.explain().startswith(f"assign.rq rows (best first): {first} at ")


def test_the_facts_store_is_small_and_gives_the_same_rows(plant: PlantGraph, small: ox.Store) -> None:
    """Every row (distance, battery, max load, the AGV's IRI) is the same on both stores, and the
    facts store holds only the AGVs' triples (no ontology)."""
    for _, vehicles, need, _, _ in CASES:
        assert choose(small, vehicles, need).rows == choose(plant.store, vehicles, need).rows
    def agvs(store: ox.Store) -> set[object]:
        return {q.subject for q in store.quads_for_pattern(None, ox.NamedNode(str(PK.isType)), AGV)}

    assert agvs(small) == agvs(plant.store) and len(agvs(small)) == 6  # the example's 2, 3 discovered, the paper one
    assert len(small) < len(plant.store) / 4


def test_the_rows_carry_distance_battery_and_max_load(plant: PlantGraph) -> None:
    choice = choose(plant.store, FLEET, Need("pick", "drop", 0.0, 0.0))
    row = choice.rows[0]
    assert row["distance"] == pytest.approx(3.0) and row["battery"] == 80.0 and row["maxLoad"] == 120.0


def test_assignment_latency(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """20 discovered vehicles (the issue's benchmark fleet), 200 assignments; printed, not asserted."""
    binding = fleet_binding([EXAMPLE])
    files = [EXAMPLE]
    for i in range(20):
        path = tmp_path / f"t--b-{i}.ttl"
        path.write_text(agv_turtle(from_factsheet("t", f"b-{i}", d.factsheet("t", f"b-{i}")), binding), encoding="utf-8")
        files.append(path)
    plant_store = load_plant(files).store
    vehicles = [live(f"b-{i}", float(i), idle=i % 3 != 0) for i in range(20)]
    for name, store in (("whole plant", plant_store), ("assignment facts", facts(plant_store))):
        times = sorted(choose(store, vehicles, Need("pick", "drop", float(k % 40), 0.0)).seconds for k in range(200))
        assert choose(store, vehicles, Need("pick", "drop", 0.0, 0.0)).vehicle == "t/b-1"  # b-0 is busy
        with capsys.disabled():
            print(f"\nassign.rq over the {name} ({len(store)} quads), example plant + 20 discovered vehicles "
                  f"(13 idle), 200 runs: p50 {statistics.median(times) * 1000:.2f} ms, p99 {times[197] * 1000:.2f} ms, "
                  f"max {times[-1] * 1000:.2f} ms")


def test_the_plant_view_renews_its_store_with_the_same_facts(tmp_path: Path) -> None:
    """PlantView hands out the assignment facts; every ``renew_every`` calls a new store with the
    same facts and no live graph (a store whose live graph was replaced many times gets slower);
    a new discovered vehicle is loaded and chosen."""
    folder = tmp_path / "discovered"
    folder.mkdir()
    view = PlantView((EXAMPLE,), folder, renew_every=3)
    first = view.current()
    base = sorted(str(q) for q in first)
    choose(first, FLEET, Need("pick", "drop", 0.0, 0.0))
    assert view.current() is first and view.current() is first  # calls 2 and 3
    renewed = view.current()
    assert renewed is not first and sorted(str(q) for q in renewed) == base  # the live graph is gone
    assert choose(renewed, [live("a-9", 1.0)], Need("pick", "drop", 0.0, 0.0)).vehicle is None
    binding = fleet_binding([EXAMPLE])
    (folder / "t--a-9.ttl").write_text(agv_turtle(from_factsheet("t", "a-9", d.factsheet("t", "a-9")), binding),
                                       encoding="utf-8")
    assert choose(view.current(), [live("a-9", 1.0)], Need("pick", "drop", 0.0, 0.0)).vehicle == "t/a-9"
    assert view.loads == 2
    with pytest.raises(ValueError, match="renew_every"):
        PlantView((EXAMPLE,), folder, renew_every=0)
