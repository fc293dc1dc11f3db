"""Which vehicle takes a task: ``assign.rq`` over the plant graph plus the live vehicle states.

The query text is a file of its own (``fleet/planner/assign.rq``) so a decision can be explained:
:func:`choose` returns the rows it decided on (best first) and the planner logs them. Before each
run the live graph (``urn:plantkg:planner:live``) is replaced with one ``plan:Live`` node per
vehicle the fleet manager knows (its connection state, whether a task of the planner holds it,
its position and battery), and one ``plan:Need`` node with the requirements (skills, payload,
minimum battery, the station's position, the interface the planner can dispatch to): values are
RDF terms in the graph, never spliced into the query's text. (kg.query's trailing ``VALUES`` is
joined after the query's FILTERs ran, so it cannot carry values a FILTER compares with.)

The store it runs on is small (:func:`facts`): ``assign-facts.rq`` copies the AGVs of the plant
graph — serial, interface, skills, properties — into a store of their own once per plant load, so
each assignment reads a few hundred triples, not the whole plant with its ontology (about 5x
faster with 20 vehicles; the choices are the same, tests/unit/fleet/test_planner_assign.py).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import pyoxigraph as ox

from kg.query import run_query

QUERY = (Path(__file__).with_name("assign.rq")).read_text(encoding="utf-8")
FACTS = (Path(__file__).with_name("assign-facts.rq")).read_text(encoding="utf-8")
PLAN = "https://w3id.org/plantkg/planner#"
LIVE_GRAPH = ox.NamedNode("urn:plantkg:planner:live")
_XSD = "http://www.w3.org/2001/XMLSchema#"
_DECIMAL, _BOOLEAN = ox.NamedNode(_XSD + "decimal"), ox.NamedNode(_XSD + "boolean")


@dataclass(frozen=True)
class Live:
    """One vehicle as the planner sees it now."""

    serial: str
    manufacturer: str  # as in its topics
    connection_state: str
    idle: bool
    x: float | None
    y: float | None
    battery: float | None = None

    @property
    def key(self) -> str:
        return f"{self.manufacturer}/{self.serial}"


@dataclass(frozen=True)
class Need:
    """What the task's next step needs of a vehicle."""

    pick_skill: str
    drop_skill: str
    x: float
    y: float
    payload: float = 0.0
    min_battery: float = 20.0
    interface: str = "vda5050"
    also: tuple[tuple[str, str, str], ...] = ()  # more (interface, pick skill, drop skill) accepted

    @property
    def options(self) -> tuple[tuple[str, str, str], ...]:
        return ((self.interface, self.pick_skill, self.drop_skill),) + self.also


@dataclass(frozen=True)
class Choice:
    vehicle: str | None  # manufacturer/serial, None when no row
    rows: tuple[dict[str, object], ...]  # the query's rows, best first (for the log)
    seconds: float

    def explain(self, limit: int = 3) -> str:
        if not self.rows:
            return "no vehicle fits (assign.rq returned no row)"
        parts = [f"{r['manufacturer']}/{r['serial']} at {r['distance']:.2f} m, battery {r['battery']}, "
                 f"max load {r['maxLoad']}" for r in self.rows[:limit]]
        return "assign.rq rows (best first): " + "; ".join(parts) + (
            f"; and {len(self.rows) - limit} more" if len(self.rows) > limit else "")


def _dec(value: float) -> ox.Literal:
    return ox.Literal(repr(float(value)), datatype=_DECIMAL)


def live_quads(vehicles: list[Live]) -> list[ox.Quad]:
    quads = []
    p = {name: ox.NamedNode(PLAN + name) for name in
         ("Live", "serial", "manufacturer", "connectionState", "idle", "x", "y", "battery")}
    rdf_type = ox.NamedNode("http://www.w3.org/1999/02/22-rdf-syntax-ns#type")
    for i, v in enumerate(vehicles):
        node = ox.NamedNode(f"urn:plantkg:planner:live:{i}")
        quads += [ox.Quad(node, rdf_type, p["Live"], LIVE_GRAPH),
                  ox.Quad(node, p["serial"], ox.Literal(v.serial), LIVE_GRAPH),
                  ox.Quad(node, p["manufacturer"], ox.Literal(v.manufacturer), LIVE_GRAPH),
                  ox.Quad(node, p["connectionState"], ox.Literal(v.connection_state), LIVE_GRAPH),
                  ox.Quad(node, p["idle"], ox.Literal("true" if v.idle else "false", datatype=_BOOLEAN),
                          LIVE_GRAPH)]
        if v.x is not None and v.y is not None:
            quads += [ox.Quad(node, p["x"], _dec(v.x), LIVE_GRAPH), ox.Quad(node, p["y"], _dec(v.y), LIVE_GRAPH)]
        if v.battery is not None:
            quads.append(ox.Quad(node, p["battery"], _dec(v.battery), LIVE_GRAPH))
    return quads


def need_quads(need: Need) -> list[ox.Quad]:
    node = ox.NamedNode("urn:plantkg:planner:need")
    rdf_type = ox.NamedNode("http://www.w3.org/1999/02/22-rdf-syntax-ns#type")
    values = {"payload": _dec(need.payload), "minBattery": _dec(need.min_battery), "x": _dec(need.x),
              "y": _dec(need.y)}
    quads = [ox.Quad(node, rdf_type, ox.NamedNode(PLAN + "Need"), LIVE_GRAPH)] + [
        ox.Quad(node, ox.NamedNode(PLAN + name), value, LIVE_GRAPH) for name, value in values.items()]
    for i, (interface, pick, drop) in enumerate(need.options):
        option = ox.NamedNode(f"urn:plantkg:planner:need:option:{i}")
        quads.append(ox.Quad(node, ox.NamedNode(PLAN + "accepts"), option, LIVE_GRAPH))
        quads += [ox.Quad(option, ox.NamedNode(PLAN + name), ox.Literal(value), LIVE_GRAPH)
                  for name, value in (("interface", interface), ("pickSkill", pick), ("dropSkill", drop))]
    return quads


def _plain(term: object) -> object:
    if term is None:
        return None
    if isinstance(term, ox.Literal):
        if term.datatype.value.startswith(_XSD) and term.datatype.value[len(_XSD):] in (
                "decimal", "double", "float", "integer", "int"):
            return float(term.value)
        return term.value
    return getattr(term, "value", str(term))


def facts(plant: ox.Store) -> ox.Store:
    """A new in-memory store with what ``assign.rq`` reads of ``plant`` (``assign-facts.rq``)."""
    result = run_query(plant, FACTS)
    small = ox.Store()
    small.extend([ox.Quad(t.subject, t.predicate, t.object) for t in result.triples])
    return small


def choose(store: ox.Store, vehicles: list[Live], need: Need) -> Choice:
    """The vehicle ``assign.rq`` ranks first for ``need`` (None when none fits), with its rows.

    ``store`` is :func:`facts` of the plant (or the plant's own store: the same rows, slower); its
    live graph is replaced."""
    began = time.perf_counter()
    store.clear_graph(LIVE_GRAPH)
    store.extend(live_quads(vehicles) + need_quads(need))
    result = run_query(store, QUERY)
    rows = []
    for row in result.rows:
        record = {name: _plain(value) for name, value in zip(result.variables, row)}
        record["distance"] = math.sqrt(float(record.pop("distance2") or 0.0))
        rows.append(record)
    seconds = time.perf_counter() - began
    first = rows[0] if rows else None
    return Choice(f"{first['manufacturer']}/{first['serial']}" if first else None, tuple(rows), seconds)
