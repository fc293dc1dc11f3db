"""The planner's state tables and the Fig. 5 split, as cases."""

from __future__ import annotations

import pytest

from fleet.planner.errors import TransitionError
from fleet.planner.split import Act, Motion, split, well_formed
from fleet.planner.states import LEG_TRANSITIONS, TASK_TRANSITIONS, LegState, TaskState, check_leg, check_task

T, L = TaskState, LegState

TASK_CASES = [  # (from, to, allowed)
    (T.RAW, T.ACTIVE, True), (T.RAW, T.ASSIGNED, False), (T.RAW, T.FINISHED, False),
    (T.ACTIVE, T.ASSIGNED, True), (T.ACTIVE, T.BEING_PROCESSED, False),
    (T.ASSIGNED, T.BEING_PROCESSED, True), (T.ASSIGNED, T.ACTIVE, True),
    (T.BEING_PROCESSED, T.FINISHED, True), (T.BEING_PROCESSED, T.ACTIVE, True),
    (T.BEING_PROCESSED, T.FAILED, True), (T.BEING_PROCESSED, T.RAW, False),
    (T.FINISHED, T.ACTIVE, False), (T.FAILED, T.ACTIVE, False), (T.WITHDRAWN, T.RAW, False),
]
LEG_CASES = [
    (L.READY, L.SENT, True), (L.READY, L.DONE, False), (L.SENT, L.ACTED, True), (L.SENT, L.DONE, True),
    (L.SENT, L.READY, True), (L.ACTED, L.DONE, True), (L.ACTED, L.READY, False), (L.DONE, L.READY, False),
]


@pytest.mark.parametrize(("old", "new", "allowed"), TASK_CASES)
def test_task_transitions(old: TaskState, new: TaskState, allowed: bool) -> None:
    if allowed:
        check_task("t1", old, new)
    else:
        with pytest.raises(TransitionError, match=f"task t1: {old.value} -> {new.value} is not allowed"):
            check_task("t1", old, new)


@pytest.mark.parametrize(("old", "new", "allowed"), LEG_CASES)
def test_leg_transitions(old: LegState, new: LegState, allowed: bool) -> None:
    if allowed:
        check_leg("t1", 0, old, new)
    else:
        with pytest.raises(TransitionError, match="sub-task 0"):
            check_leg("t1", 0, old, new)


def test_final_states_have_no_way_out_and_every_state_is_in_the_tables() -> None:
    assert set(TASK_TRANSITIONS) == set(TaskState) and set(LEG_TRANSITIONS) == set(LegState)
    assert all(not TASK_TRANSITIONS[s] for s in TaskState if s.final)


m1, m2, m3 = Motion("a", 0, 0), Motion("b", 1, 0), Motion("c", 2, 0)
pick, drop, wait = Act("pick"), Act("drop"), Act("wait")
SPLIT_CASES = [  # (items, expected sub-tasks) — the paper's Fig. 5
    ((m1, pick, m2, drop), ((m1, pick), (m2, drop))),  # an action followed by a motion: split
    ((m1, m2, pick, drop), ((m1, m2, pick, drop),)),  # motions then actions: one sub-task
    ((m1, pick, wait, m2), ((m1, pick, wait), (m2,))),  # a wait ends the sub-task
    ((m1, wait, pick), ((m1, wait), (pick,))),  # nothing after a wait in the same sub-task
    ((m1, pick, m2, m3, drop, wait), ((m1, pick), (m2, m3, drop, wait))),
    ((), ()),
]


@pytest.mark.parametrize(("items", "expected"), SPLIT_CASES)
def test_split_follows_fig5(items: tuple, expected: tuple) -> None:
    got = split(items)
    assert got == expected
    assert all(well_formed(s) for s in got)
    assert tuple(i for s in got for i in s) == items  # nothing lost or reordered


def test_well_formed_refuses_an_action_before_a_motion_and_a_wait_not_last() -> None:
    assert not well_formed((m1, pick, m2))
    assert not well_formed((m1, wait, pick))
    assert well_formed((m1, m2, pick, wait))
