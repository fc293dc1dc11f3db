"""Ownership in the plan, as cases as data: tests/cases/plan/owner-*/.

Each owner case holds, beside the usual desired/observed/expected_plan.json (checked by
test_plan_cases.py like every case), ``expected_foreign.json`` (what the plan lists as foreign and
leaves alone) and ``expected_plan_prune.json`` (the plan with ``--prune``: the projection of
test_plan_cases plus its foreign list). The rules (engine.plan): a plant changes only what it owns;
another plant's things are never deleted, with or without prune; what nobody owns is deleted only
with prune; a broker nobody owns that the plant declares is refused (import it); a topic or bridge
nobody owns on the plant's own broker is adopted.
"""

from __future__ import annotations

import json
from typing import Any

import pytest

from engine.model import Action, DesiredState, ObservedState, to_dict
from engine.plan import Ownership, destroy_plan, ownership, plan
from tests.unit.fake_agents import FakeFleet
from tests.unit.plan_data import CASES, case_names, load_case
from tests.unit.test_plan_cases import project

OWNER_CASES = [n for n in case_names() if n.startswith("owner-")]


def _expected(name: str, file: str) -> Any:
    return json.loads((CASES / name / file).read_text(encoding="utf-8"))


def test_there_are_owner_cases() -> None:
    assert len(OWNER_CASES) >= 6


@pytest.mark.parametrize("name", OWNER_CASES)
def test_foreign_things_are_listed(name: str) -> None:
    desired, observed, _ = load_case(name)
    assert [to_dict(f) for f in plan(desired, observed).foreign] == _expected(name, "expected_foreign.json")


@pytest.mark.parametrize("name", OWNER_CASES)
def test_prune_plan(name: str) -> None:
    desired, observed, _ = load_case(name)
    result = plan(desired, observed, prune=True)
    got = {**project(result), "foreign": [to_dict(f) for f in result.foreign]}
    assert got == _expected(name, "expected_plan_prune.json")


def _owner_of(observed: ObservedState, address: str) -> str | None:
    for b in observed.brokers:
        if b.spec.address == address:
            return b.owner
        for t in b.topics:
            if f"topic.{b.spec.id}.{t.name}" == address:
                return t.owner
    for bridge in observed.bridges:
        if bridge.spec.address == address:
            return bridge.owner
    raise KeyError(address)


@pytest.mark.parametrize("name", OWNER_CASES)
@pytest.mark.parametrize("prune", [False, True])
def test_another_plants_things_are_never_deleted(name: str, prune: bool) -> None:
    desired, observed, _ = load_case(name)
    for change in plan(desired, observed, prune=prune).pending:
        if change.action is Action.DELETE:
            whose = ownership(_owner_of(observed, change.address), desired.owner)
            assert whose is Ownership.MINE or (prune and whose is Ownership.NOBODY), change


@pytest.mark.parametrize("name", [n for n in OWNER_CASES if load_case(n)[2]["applicable"]])
def test_applying_with_prune_converges_and_keeps_the_foreign(name: str) -> None:
    desired, observed, _ = load_case(name)
    fleet = FakeFleet.from_observed(observed)
    fleet.apply_directly(plan(desired, observed, prune=True), desired)
    again = plan(desired, fleet.observed(), prune=True)
    assert again.empty, [c.address for c in again.pending]
    others = {f.address for f in plan(desired, observed).foreign if f.owner is not None}
    assert others == {f.address for f in again.foreign}
    assert not [f for f in again.foreign if f.owner is None], "prune leaves nothing unowned"


@pytest.mark.parametrize("name", OWNER_CASES)
def test_destroy_deletes_exactly_what_the_plant_owns(name: str) -> None:
    desired, observed, _ = load_case(name)
    result = destroy_plan(desired, observed)
    deleted = {c.address for c in result.pending if not c.address.startswith("topic.")}
    assert all(c.action is Action.DELETE for c in result.pending)
    if desired.owner is None:
        ours = {b.id for b in desired.brokers}
        expected = {b.spec.address for b in observed.brokers if b.spec.id in ours and b.owner is None}
        expected |= {b.spec.address for b in observed.bridges if b.spec.local.id in ours and b.owner is None}
    else:
        expected = {b.spec.address for b in observed.brokers if b.owner == desired.owner}
        expected |= {b.spec.address for b in observed.bridges if b.owner == desired.owner}
    assert deleted == expected
    listed = {f.address for f in result.foreign}
    assert listed.isdisjoint(deleted)


def test_destroy_of_an_owned_plant_removes_brokers_it_no_longer_names() -> None:
    desired, observed, _ = load_case("owner-bridges")
    result = destroy_plan(DesiredState(owner=desired.owner), observed)
    assert {c.address for c in result.pending if c.address.startswith("broker.")} == \
        {"broker.a", "broker.c", "broker.d"}


@pytest.mark.parametrize(("owner", "mine", "whose"), [
    ("p", "p", Ownership.MINE), (None, None, Ownership.MINE), (None, "p", Ownership.NOBODY),
    ("q", "p", Ownership.OTHER), ("q", None, Ownership.OTHER),
])
def test_ownership(owner: str | None, mine: str | None, whose: Ownership) -> None:
    assert ownership(owner, mine) is whose
