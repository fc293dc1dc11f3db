"""The task book of the paper's Fig. 5: what is accepted, refused, run, and when a task has ended."""

from __future__ import annotations

from typing import Any

import pytest

from fleet.paper.messages import ActionItem, MotionItem
from fleet.paper.tasks import TaskBook
from tests.unit.fleet.paper_cases import action, motion

T1 = "11111111-1111-4111-8111-111111111111"
T2 = "22222222-2222-4222-8222-222222222222"


def m(task: str = T1, seq: int = 0) -> MotionItem:
    return MotionItem.from_json(motion(task, seq))


def a(kind: str = "wait", task: str = T1, seq: int = 1) -> ActionItem:
    return ActionItem.from_json(action(kind, task, seq))


# (items offered in order, expected verdict per item: "ok", "dup" or a fragment of the reason)
SEQUENCES: list[tuple[str, list[Any], list[str]]] = [
    ("motions then actions then wait", [m(seq=0), m(seq=1), a("load", seq=2), a("wait", seq=3)], ["ok"] * 4),
    ("only actions", [a("idle", seq=0), a("wait", seq=1)], ["ok", "ok"]),
    ("motion after an action", [m(seq=0), a("load", seq=1), m(seq=2)], ["ok", "ok", "a motion after an action"]),
    ("action before a motion", [a("load", seq=0), m(seq=1)], ["ok", "a motion after an action"]),
    ("sequence going back", [m(seq=5), m(seq=5)], ["ok", "sequence 5 is not after 5"]),
    ("sequence lower", [m(seq=5), a("wait", seq=2)], ["ok", "sequence 2 is not after 5"]),
    ("another task while one is open", [m(T1, 0), m(T2, 0)], ["ok", f"task {T1} is still open"]),
    ("the next task after a wait", [m(T1, 0), a("wait", T1, 1), m(T2, 0), a("wait", T2, 1)], ["ok"] * 4),
    ("an item of an ended task", [m(T1, 0), a("wait", T1, 1), m(T1, 2)], ["ok", "ok", "already ended"]),
]


@pytest.mark.parametrize(("label", "items", "expected"), SEQUENCES, ids=[s[0] for s in SEQUENCES])
def test_offers(label: str, items: list[Any], expected: list[str]) -> None:
    book = TaskBook()
    for item, want in zip(items, expected, strict=True):
        verdict = book.offer(item)
        if want == "ok":
            assert verdict.accepted, verdict.reason
        else:
            assert not verdict.accepted and not verdict.duplicate and want in verdict.reason, verdict
    assert len(book.pending) == expected.count("ok")


def test_the_same_item_again_is_a_duplicate_not_an_error() -> None:
    book = TaskBook()
    item = m()
    assert book.offer(item).accepted
    again = book.offer(item)
    assert again.duplicate and not again.accepted and not again.reason
    assert len(book.pending) == 1


def test_a_full_queue_refuses() -> None:
    book = TaskBook(max_pending=2)
    assert book.offer(m(seq=0)).accepted and book.offer(m(seq=1)).accepted
    assert "already waiting (at most 2)" in book.offer(m(seq=2)).reason


def test_steps_run_one_at_a_time_and_a_wait_ends_the_task() -> None:
    book = TaskBook()
    items = [m(seq=1), a("load", seq=2), a("wait", seq=3)]
    for item in items:
        book.offer(item)
    assert book.open_task is None  # closed for new items by the wait
    done = []
    while (step := book.start_next()) is not None:
        assert book.start_next() is None  # one at a time
        assert book.finished_task_id == ""
        done.append(book.finish(ok=True).item)
    assert done == items
    assert (book.last_finished_sequence, book.finished_task_id) == (3, T1)


def test_a_failed_step_does_not_count_as_finished() -> None:
    book = TaskBook()
    book.offer(a("charge", seq=4))
    book.start_next()
    book.finish(ok=False)
    assert book.last_finished_sequence == -1
