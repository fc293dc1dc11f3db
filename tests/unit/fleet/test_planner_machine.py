"""LoTLan tasks -> planner tasks, conditions, and the transitions of a transport, as cases."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import pytest

import fleet.lotlan
from fleet.lotlan.model import Program
from fleet.planner import build, conditions, machine
from fleet.planner.errors import BuildError, TransitionError
from fleet.planner.machine import Now, Rules, VehicleView
from fleet.planner.model import Task
from fleet.planner.states import LegState, TaskState
from tests.unit.fleet.planner_data import JOBS, SITE


@pytest.fixture(scope="module")
def program() -> Program:
    return fleet.lotlan.parse(JOBS, "jobs.tl")


def rules_for(program: Program, name: str) -> Rules:
    t = program.task(name)
    return Rules(t.triggered_by, t.finished_by, tuple((u.step.triggered_by, u.step.finished_by)
                                                       for u in (t.pickup, t.delivery)))


class World:
    """Events with sequence numbers and vehicle views, as the service keeps them."""

    def __init__(self) -> None:
        self.events: list[tuple[int, str, Any]] = []
        self.vehicles: dict[str, VehicleView] = {}
        self.done: dict[str, frozenset[str]] = {}

    def fire(self, name: str, value: Any = True) -> None:
        self.events.append((len(self.events) + 1, name, value))

    def now(self) -> Now:
        def after(seq: int) -> dict[str, Any]:
            return {n: v for s, n, v in self.events if s > seq}
        return Now(len(self.events), after, self.done, self.vehicles)


def test_a_transport_becomes_two_sub_tasks_at_the_map_stations(program: Program) -> None:
    task = build.build_task("j1-first-1", "j1", program.task("first"), 1, SITE)
    assert [(leg.station, leg.x, leg.y, leg.actions, leg.step) for leg in task.legs] == [
        ("load-1", 2.0, 6.0, ("pick",), "atLoad"), ("unload-1", 10.0, 6.0, ("drop",), "atUnload")]
    assert task.state is TaskState.RAW and Task.from_json(task.to_json()) == task


def test_a_location_not_on_the_map_and_a_time_trigger_are_refused_with_file_and_line() -> None:
    text = JOBS.replace('name = "unload-2"', 'name = "nowhere"') + (
        'Time morning\n    timing = "30 8 * * *"\nEnd\n\nTask third\n    Transport\n    From atLoad\n'
        '    To atUnload\n    TriggeredBy morning\nEnd\n')
    with pytest.raises(BuildError) as caught:
        build.check_program(fleet.lotlan.parse(text, "jobs.tl"), SITE)
    message = caught.value.message
    assert "jobs.tl:16: Location otherUnload (name 'nowhere') is no station" in message
    assert "jobs.tl:69: Task third waits for Time morning" in message


CONDITION_CASES = [  # (expression text as a TriggeredBy, events, done, holds)
    ("loaded", {"loaded": True}, (), True),
    ("loaded", {}, (), False),
    ("loaded == True", {"loaded": True}, (), True),
    ("loaded == True", {"loaded": False}, (), False),
    ("!loaded", {}, (), True),
    ("loaded and unloaded", {"loaded": True}, (), False),
    ("loaded or unloaded", {"unloaded": True}, (), True),
    ("first.IsDone", {}, ("first",), True),
    ("first.IsDone", {}, (), False),
]


@pytest.mark.parametrize(("text", "events", "done", "expected"), CONDITION_CASES)
def test_conditions(text: str, events: dict, done: tuple, expected: bool) -> None:
    program = fleet.lotlan.parse(JOBS + f"\nTask probe\n    Transport\n    From atLoad\n    To atUnload\n"
                                        f"    TriggeredBy {text}\nEnd\n", "probe.tl")
    expr = program.task("probe").triggered_by
    assert conditions.holds(expr, events, frozenset(done)) is expected


def run(task: Task, rules: Rules, world: World) -> tuple[Task, list[str], list[machine.SendOrder]]:
    steps, sends = machine.advance(task, rules, world.now())
    return (steps[-1][0] if steps else task), [note for _, note in steps], sends


def finished_view(key: str, send: machine.SendOrder, status: str = "FINISHED") -> VehicleView:
    return VehicleView(key, True, send.order_id, send.station,
                       tuple((f"{send.order_id}-{send.station}-{i}", status) for i in range(len(send.actions))))


def test_a_transport_runs_motions_then_actions_and_waits_for_the_operator(program: Program) -> None:
    world, rules = World(), rules_for(program, "first")
    task = build.build_task("j1-first-1", "j1", program.task("first"), 1, SITE)
    task, notes, _ = run(task, rules, world)
    assert task.state is TaskState.ACTIVE and notes == ["RAW -> ACTIVE"]
    task = machine.assign(task, "m/agv-1", "nearest idle")
    task, notes, sends = run(task, rules, world)
    assert task.state is TaskState.BEING_PROCESSED and [s.station for s in sends] == ["load-1"]
    assert sends[0].order_id == "j1-first-1-0-1" and sends[0].actions == ("pick",)
    world.fire("loaded")  # pressed before the vehicle arrived: does not count
    world.vehicles["m/agv-1"] = finished_view("m/agv-1", sends[0])
    task, notes, sends = run(task, rules, world)
    assert notes == ["sub-task 0 SENT -> ACTED (waiting for its FinishedBy)"] and not sends
    world.fire("loaded")
    task, notes, sends = run(task, rules, world)
    assert notes[:2] == ["sub-task 0 ACTED -> DONE", "sub-task 1 READY -> SENT (j1-first-1-1-1 to m/agv-1)"]
    assert [s.station for s in sends] == ["unload-1"]
    world.vehicles["m/agv-1"] = finished_view("m/agv-1", sends[0])
    world.fire("unloaded")  # before the drop finished: the window opens at ACTED
    task, notes, _ = run(task, rules, world)
    assert task.legs[1].state is LegState.ACTED
    world.fire("unloaded")
    task, notes, _ = run(task, rules, world)
    assert notes == ["sub-task 1 ACTED -> DONE", "-> FINISHED"] and task.state is TaskState.FINISHED


def test_a_failed_action_fails_the_task_and_a_lost_vehicle_reassigns_only_what_is_not_done(program: Program) -> None:
    world, rules = World(), rules_for(program, "second")
    world.done["j1"] = frozenset({"first"})
    task = build.build_task("j1-second-1", "j1", program.task("second"), 1, SITE)
    task, _, _ = run(task, rules, world)
    task, _, sends = run(machine.assign(task, "m/agv-1", "q"), rules, world)
    world.vehicles["m/agv-1"] = finished_view("m/agv-1", sends[0])
    task, notes, sends = run(task, rules, world)  # no FinishedBy: DONE at once, the drop is sent
    assert notes[0] == "sub-task 0 SENT -> DONE" and sends[0].order_id == "j1-second-1-1-1"
    lost = machine.vehicle_lost(task, "m/agv-1 is CONNECTIONBROKEN")
    assert lost.state is TaskState.ACTIVE and lost.vehicle == ""
    assert [leg.state for leg in lost.legs] == [LegState.DONE, LegState.READY]
    again, _, sends = run(machine.assign(lost, "m/agv-2", "q"), rules, world)
    assert [(s.vehicle, s.station, s.order_id) for s in sends] == [("m/agv-2", "unload-2", "j1-second-1-1-2")]
    world.vehicles["m/agv-2"] = finished_view("m/agv-2", sends[0], "FAILED")
    failed, notes, _ = run(again, rules, world)
    assert failed.state is TaskState.FAILED and "FAILED on m/agv-2" in failed.reason
    with pytest.raises(TransitionError):
        machine.assign(failed, "m/agv-3", "q")


def test_a_trigger_on_another_task_keeps_the_task_raw(program: Program) -> None:
    world = World()
    task = build.build_task("j1-second-1", "j1", program.task("second"), 1, SITE)
    assert run(task, rules_for(program, "second"), world)[0].state is TaskState.RAW
    world.done["j1"] = frozenset({"first"})
    assert run(task, rules_for(program, "second"), world)[0].state is TaskState.ACTIVE


def test_a_state_of_another_order_is_no_news(program: Program) -> None:
    world, rules = World(), rules_for(program, "second")
    world.done["j1"] = frozenset({"first"})
    task, _, _ = run(build.build_task("t", "j1", program.task("second"), 1, SITE), rules, world)
    task, _, sends = run(machine.assign(task, "m/a", "q"), rules, world)
    world.vehicles["m/a"] = replace(finished_view("m/a", sends[0]), order_id="someone-else")
    assert run(task, rules, world)[1] == []
