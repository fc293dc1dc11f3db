"""Sub-tasks for paper-channel vehicles, without processes: the items the planner writes are the
paper's messages (checked by fleet/paper's own parsers) and the vehicle's own Fig. 5 bookkeeper
(fleet/paper/tasks.py) accepts them in order and ends the task; the status read back becomes
"finished" or "failed" for the right leg only; the manager's 503 makes the fleet wait."""

from __future__ import annotations

from typing import Any

import pytest

from fleet.manager.client import ManagerRefusedError
from fleet.paper.messages import ActionItem, ActionKind, MotionItem
from fleet.paper.tasks import TaskBook
from fleet.planner import paperids
from fleet.planner.errors import PlannerError
from fleet.planner.machine import SendOrder, leg_progress
from fleet.planner.model import Leg
from fleet.planner.paper import attributes, items, motion_accepted
from fleet.planner.vehicles import Fleet, Vehicle, paper_view
from tests.unit.fleet.planner_data import SITE

CASES = [  # (the sub-task's abstract actions, the paper actions the vehicle runs, in order)
    (("pick",), ["load", "wait"]),
    (("drop",), ["unload", "wait"]),
    ((), ["wait"]),
    (("pick", "wait"), ["load", "wait"]),
    (("pick", "drop"), ["load", "unload", "wait"]),
]


def send(order_id: str = "j1-first-1-0-1", actions: tuple[str, ...] = ("pick",)) -> SendOrder:
    return SendOrder("j1-first-1", 0, "/cart-1", order_id, "load-1", 2.0, 6.0, actions)


@pytest.mark.parametrize("actions, expected", CASES)
def test_items_are_the_papers_messages_motion_first_then_actions_ending_with_a_wait(
        actions: tuple[str, ...], expected: list[str]) -> None:
    plan = items(send(actions=actions), SITE)
    motions = [MotionItem.from_json(m) for m in plan.motions]
    acts = [ActionItem.from_json(a) for a in plan.actions]
    assert [a.action.value for a in acts] == expected
    assert motions[0].point == (2.0, 6.0) and motions[0].task_id == plan.task_id
    book = TaskBook()
    verdicts = [book.offer(i) for i in [*motions, *acts]]
    assert all(v.accepted for v in verdicts), verdicts
    assert book.open_task is None  # the wait ended the task
    while (step := book.start_next()) is not None:
        book.finish(True)
    assert book.finished_task_id == plan.task_id
    assert book.last_finished_sequence == max(a.sequence for a in acts)
    assert acts[-1].action is ActionKind.WAIT


def test_items_are_the_same_for_a_resend_and_new_for_another_attempt() -> None:
    assert items(send(), SITE) == items(send(), SITE)
    other = items(send("j1-first-1-0-2"), SITE)
    assert other.task_id != items(send(), SITE).task_id
    assert not {m["motion_id"] for m in other.motions} & {m["motion_id"] for m in items(send(), SITE).motions}


def test_a_second_task_after_the_first_is_accepted_by_the_vehicle() -> None:
    book = TaskBook()
    for order in ("j1-a-1-0-1", "j1-a-1-1-1"):
        plan = items(send(order), SITE)
        for item in [*map(MotionItem.from_json, plan.motions), *map(ActionItem.from_json, plan.actions)]:
            assert book.offer(item).accepted


def test_an_unknown_action_is_refused_naming_it() -> None:
    with pytest.raises(PlannerError) as caught:
        items(send(actions=("weld",)), SITE)
    assert "'weld'" in caught.value.message


def test_the_vehicles_limits_come_from_its_description() -> None:
    status = {"physical": {"max_velocity": [1.5, 0.0, 2.0], "max_acceleration": [0.8, 0.0, 1.0]}}
    assert items(send(), SITE, status).motions[0]["max_velocity"] == [1.5, 0.0, 2.0]
    assert items(send(), SITE, {"physical": {"max_velocity": "fast"}}).motions[0]["max_velocity"] == [1.0, 0.0, 1.0]


def test_attributes_are_one_per_field_with_ngsi_types() -> None:
    got = attributes({"task_id": "x", "sequence": 3, "point": [1.0, 2.0], "flag": True})
    assert got == {"task_id": {"type": "Text", "value": "x"}, "sequence": {"type": "Number", "value": 3},
                   "point": {"type": "StructuredValue", "value": [1.0, 2.0]},
                   "flag": {"type": "Boolean", "value": True}}


def leg(order_id: str = "j1-first-1-0-1", actions: tuple[str, ...] = ("pick",)) -> Leg:
    return Leg(0, "atLoad", "load-1", 2.0, 6.0, actions, order_id=order_id)


def status(**fields: Any) -> dict[str, Any]:
    return {"state": "IDLE", "task_id": "", "finished_task_id": "", "errors": [], **fields}


def test_progress_of_a_paper_leg_follows_the_status() -> None:
    oid = "j1-first-1-0-1"
    task = paperids.task_uuid(oid)
    view = paper_view("/cart-1", True, status(task_id=task, state="MOVING"))
    assert (view.order_id, view.ended, leg_progress(leg(), view)) == (task, False, "")
    view = paper_view("/cart-1", True, status(finished_task_id=task))
    assert (view.ended, leg_progress(leg(), view)) == (True, "finished")
    assert leg_progress(leg("j1-first-1-0-2"), view) == ""  # another attempt's task: not this leg
    other = paper_view("/cart-1", True, status(finished_task_id=task, task_id=paperids.task_uuid("x")))
    assert leg_progress(leg(), other) == ""  # it runs another task now: ended, but not the view's task
    failed = paper_view("/cart-1", True, status(errors=[{"channel": "action_channel",
                                                        "item_id": paperids.action_uuid(oid, 0), "reason": "r"}]))
    assert leg_progress(leg(), failed) == "failed"
    stale = paper_view("/cart-1", True, status(errors=[{"channel": "action_channel",
                                                       "item_id": paperids.action_uuid("old", 0), "reason": "r"}]))
    assert leg_progress(leg(), stale) == ""


def test_the_motion_counts_as_accepted_when_the_vehicle_runs_or_finished_it() -> None:
    plan = items(send(), SITE)
    first = paperids.first_sequence("j1-first-1-0-1")
    assert not motion_accepted(None, plan)
    assert not motion_accepted(status(last_finished_sequence=first + 7), plan)
    assert motion_accepted(status(task_id=plan.task_id), plan)
    assert motion_accepted(status(last_finished_sequence=first), plan)
    assert not motion_accepted(status(last_finished_sequence=first, task_id="another"), plan)


def test_a_paper_vehicle_has_its_position_and_battery_from_its_entity() -> None:
    v = Vehicle("/cart-1", "cart-1", "", "paper-channels", True, "ONLINE",
                {"pose": {"x": 1.0, "y": 2.5, "theta": 0.0}, "battery": 77.0})
    assert (v.position(), v.battery(), v.view().paper) == ((1.0, 2.5), 77.0, True)


class Client:
    def __init__(self, answers: list[Any]) -> None:
        self.answers = answers
        self.url = "http://127.0.0.1:1"

    def vehicles(self) -> Any:
        answer = self.answers.pop(0)
        if isinstance(answer, Exception):
            raise answer
        return answer


def test_the_fleet_waits_while_the_manager_is_not_ready_and_keeps_its_list() -> None:
    row = {"serial": "cart-1", "topicManufacturer": "", "interface": "paper-channels", "connectionState": "ONLINE"}
    looked: list[str] = []
    fleet = Fleet(Client([[row], ManagerRefusedError(503, "NotReady"), [row]]),  # type: ignore[arg-type]
                  lambda agv: looked.append(agv) or {"task_id": "t"})
    fleet.refresh()
    assert fleet.reachable and fleet.vehicles()["/cart-1"].state == {"task_id": "t"}
    fleet.refresh()
    assert (fleet.reachable, fleet.waiting) == (False, True) and list(fleet.vehicles()) == ["/cart-1"]
    fleet.refresh()
    assert (fleet.reachable, fleet.waiting, looked) == (True, False, ["cart-1", "cart-1"])


class Ngsi:
    """The context broker's surface as the sender uses it: writes recorded, or refused."""

    def __init__(self) -> None:
        self.written: list[tuple[str, dict[str, Any]]] = []
        self.fail = False

    def write(self, entity_id: str, item: dict[str, Any]) -> None:
        if self.fail:
            raise PlannerError("the context broker does not answer")
        self.written.append((entity_id, item))


def test_the_sender_writes_the_motion_then_the_actions_once_the_vehicle_runs_the_task() -> None:
    from fleet.planner.paper import PaperSender

    ngsi = Ngsi()
    sender = PaperSender(ngsi, SITE, rewrite=60.0)  # type: ignore[arg-type]
    plan = items(send(), SITE)
    sender(send(), status(), "cart-1")
    sender(send(), status(), "cart-1")  # not accepted yet, rewrite not due: nothing
    assert [e for e, _ in ngsi.written] == ["urn:ngsi-ld:Thing:cart-1:motion_channel"]
    sender(send(), status(task_id=plan.task_id), "cart-1")
    assert [i["action"] for e, i in ngsi.written[1:]] == ["load", "wait"]
    assert {e for e, _ in ngsi.written[1:]} == {"urn:ngsi-ld:Thing:cart-1:action_channel"}
    sender(send(), status(task_id=plan.task_id), "cart-1")
    assert len(ngsi.written) == 3  # written once


def test_a_failed_write_is_retried_after_a_pause_not_on_every_tick() -> None:
    from fleet.planner.paper import PaperSender

    ngsi = Ngsi()
    ngsi.fail = True
    sender = PaperSender(ngsi, SITE, rewrite=60.0)  # type: ignore[arg-type]
    with pytest.raises(PlannerError):
        sender(send(), status(), "cart-1")
    ngsi.fail = False
    sender(send(), status(), "cart-1")  # within the pause: not tried
    assert ngsi.written == []
    sender._retry_at.clear()
    sender(send(), status(), "cart-1")
    assert len(ngsi.written) == 1
