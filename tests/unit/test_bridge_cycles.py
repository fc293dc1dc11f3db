"""engine.derived.bridge_cycles: bridges forwarding a topic round 3+ brokers are refused; pairs and chains
of two-way bridges are not.

The plants are data (tests/cases/bridge-cycles/<case>/plant.ttl with expected.json): each is valid
for the shapes, is reasoned and derived, and either derives (``"refused": false``) or raises
BridgeCycleError naming the expected cycles, broker by broker in order — with the fast reasoner
and with owlready2/HermiT, so the bridges R1 derives are the rules' own.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from engine.derived.bridge_cycles import BridgeCycle, BridgeCycleError, find_cycle, find_cycles
from engine.derived.bridge_pairs import DirectedBridge
from engine.derive import derive
from engine.reasoning.reason import reason
from kg.errors import EXIT_UNUSABLE
from kg.load import load_plant
from kg.validate import validate

CASES = Path(__file__).resolve().parents[1] / "cases" / "bridge-cycles"
CASE_NAMES = sorted(p.name for p in CASES.iterdir() if (p / "plant.ttl").is_file())


def test_cases_exist() -> None:
    assert {"mosquitto-3-cycle", "mosquitto-4-cycle", "mixed-through-kafka", "two-way-pair"} <= set(CASE_NAMES)


@pytest.mark.parametrize("engine", ["fast", "owlready2"])  # the rules' own reasoner (HermiT) agrees
@pytest.mark.parametrize("name", CASE_NAMES)
def test_case(name: str, engine: str) -> None:
    expected = json.loads((CASES / name / "expected.json").read_text())
    plant = load_plant([CASES / name / "plant.ttl"])
    report = validate(plant)
    assert report.conforms, f"{name}: the case plant must be valid, so only the cycle can refuse it"
    reason(plant, engine=engine)  # type: ignore[arg-type]
    if not expected["refused"]:
        desired = derive(plant)
        assert desired.bridges, f"{name}: an accepted case still has its bridges"
        return
    with pytest.raises(BridgeCycleError) as caught:
        derive(plant)
    error = caught.value
    got = [{"brokers": list(c.brokers), "topics": list(c.topics), "asserted": list(c.asserted)}
           for c in error.cycles]
    assert got == expected["cycles"]
    assert error.exit_code == EXIT_UNUSABLE
    for cycle in expected["cycles"]:  # the message names every broker of the cycle, in order
        path = " -> ".join([*cycle["brokers"], cycle["brokers"][0]])
        assert path in str(error)
    assert "remove one pk:bridgesTo" in str(error)


@pytest.mark.parametrize(("edges", "cycle"), [
    ([], None),
    ([("a", "b")], None),
    ([("a", "b"), ("b", "a")], None),  # the merged two-way pair
    ([("a", "b"), ("b", "a"), ("b", "c"), ("c", "b"), ("c", "d"), ("d", "c")], None),  # a chain
    ([("a", "b"), ("b", "c"), ("a", "c")], None),  # a diamond delivers twice, but does not loop
    ([("b", "c"), ("c", "a"), ("a", "b")], ("a", "b", "c")),
    ([("a", "b"), ("b", "a"), ("b", "c"), ("c", "a")], ("a", "b", "c")),  # one way closes it
    ([("a", "b"), ("b", "c"), ("c", "d"), ("d", "e"), ("e", "a"), ("a", "x")], ("a", "b", "c", "d", "e")),
    ([(x, y) for x in "pqrs" for y in "pqrs" if {x, y} in ({"p", "q"}, {"q", "r"}, {"r", "s"}, {"s", "p"})],
     ("p", "q", "r", "s")),  # a ring of two-way pairs
    ([("a", "a")], None),  # a self-bridge is the shapes' (Broker-bridgeNotSelf), not a cycle here
])
def test_find_cycle(edges: list[tuple[str, str]], cycle: tuple[str, ...] | None) -> None:
    found = find_cycle(edges)
    assert found == cycle
    if found is not None:  # whatever the rotation, every hop of the answer is an edge
        hops = {(found[i], found[(i + 1) % len(found)]) for i in range(len(found))}
        assert hops <= set(edges)


def test_find_cycles_groups_topics_and_keeps_per_topic_hops() -> None:
    bridges = [
        DirectedBridge("a", "b", frozenset({"t", "u"}), asserted=True),
        DirectedBridge("b", "c", frozenset({"t", "u"}), asserted=False),
        DirectedBridge("c", "a", frozenset({"t", "u", "v"}), asserted=True),
        DirectedBridge("c", "d", frozenset({"v"}), asserted=True),
        DirectedBridge("d", "c", frozenset({"v"}), asserted=True),
    ]
    assert find_cycles(bridges) == [BridgeCycle(("a", "b", "c"), ("t", "u"), (True, False, True))]
    bridges[1] = DirectedBridge("b", "c", frozenset({"t"}), asserted=False)  # u no longer goes round
    assert find_cycles(bridges) == [BridgeCycle(("a", "b", "c"), ("t",), (True, False, True))]
