"""Planning cases as data: tests/cases/plan/<name>/{desired,observed,expected_plan}.json.

``expected_plan.json`` holds every change in order (address, action, reason, and for updates and
replacements the fields that differ as [before, after]), the refusals, the unreachable hosts, the
summary and whether the plan can be applied. Adding a case is adding a folder.
"""

from __future__ import annotations

from typing import Any

import pytest

from engine.model import Action, Plan
from engine.plan import plan
from engine.render.plan import summary_counts
from tests.unit.plan_data import case_names, load_case


def project(result: Plan) -> dict[str, Any]:
    """The plan in the shape of expected_plan.json."""
    changes = []
    for change in result.changes:
        item: dict[str, Any] = {"address": change.address, "action": change.action.value}
        if change.reason:
            item["reason"] = change.reason
        if change.action in (Action.UPDATE, Action.REPLACE):
            before, after = change.before or {}, change.after or {}
            item["diff"] = {k: [before.get(k), after.get(k)] for k in after if before.get(k) != after.get(k)}
        changes.append(item)
    return {
        "applicable": result.applicable,
        "summary": summary_counts(result),
        "changes": changes,
        "refusals": [{"address": r.address, "reason": r.reason} for r in result.refusals],
        "unreachable": list(result.unreachable),
    }


def test_there_are_enough_cases() -> None:
    assert len(case_names()) >= 12


@pytest.mark.parametrize("name", case_names())
def test_plan_case(name: str) -> None:
    desired, observed, expected = load_case(name)
    assert project(plan(desired, observed)) == expected


@pytest.mark.parametrize("name", case_names())
def test_plan_is_pure_and_deterministic(name: str) -> None:
    desired, observed, _ = load_case(name)
    assert plan(desired, observed) == plan(desired, observed)


@pytest.mark.parametrize("name", case_names())
def test_order_brokers_topics_bridges_then_deletes(name: str) -> None:
    desired, observed, _ = load_case(name)
    result = plan(desired, observed)
    kinds = [c.address.split(".", 1)[0] for c in result.changes if c.action is not Action.DELETE]
    assert kinds == sorted(kinds, key=["broker", "topic", "bridge"].index)
    actions = [c.action for c in result.changes]
    if Action.DELETE in actions:
        first = actions.index(Action.DELETE)
        assert all(a is Action.DELETE for a in actions[first:]), "deletes come last"
    # a deleted broker's topics are deleted before it
    deleted = [c.address for c in result.changes if c.action is Action.DELETE]
    for i, address in enumerate(deleted):
        if address.startswith("broker."):
            broker = address.split(".", 1)[1]
            later = [a for a in deleted[i + 1:] if a.startswith(f"topic.{broker}.")]
            assert not later, f"{later} after {address}"


def _applicable(name: str) -> bool:
    desired, observed, _ = load_case(name)
    return plan(desired, observed).applicable


@pytest.mark.parametrize("name", [n for n in case_names() if _applicable(n)])
def test_applying_the_plan_to_a_model_converges(name: str) -> None:
    """If an agent did exactly what the plan says, planning again would find nothing to do.
    (Cases whose plan is not applicable are refused, never applied: checked by the case files.)"""
    from tests.unit.fake_agents import FakeFleet

    desired, observed, _ = load_case(name)
    result = plan(desired, observed)
    fleet = FakeFleet.from_observed(observed)
    fleet.apply_directly(result, desired)
    again = plan(desired, fleet.observed())
    assert again.empty, [c.address for c in again.pending]
