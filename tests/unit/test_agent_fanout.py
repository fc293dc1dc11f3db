"""engine.agent.fanout.each: every item its own outcome, in order, from at most N threads."""

from __future__ import annotations

import threading

from engine.agent.fanout import each


def test_each_item_answers_its_result_or_its_error_in_order() -> None:
    def work(n: int) -> int:
        if n % 2:
            raise ValueError(f"odd {n}")
        return n * 10

    outcomes = each(work, range(5), threads=3)
    assert [o if isinstance(o, int) else str(o) for o in outcomes] == [0, "odd 1", 20, "odd 3", 40]


def test_the_items_run_at_once_on_at_most_the_threads_asked() -> None:
    """Two items meet at a barrier (they run together); never more than two run at once."""
    meet = threading.Barrier(2, timeout=10)
    lock, running, most = threading.Lock(), [0], [0]

    def work(n: int) -> str:
        with lock:
            running[0] += 1
            most[0] = max(most[0], running[0])
        meet.wait()
        with lock:
            running[0] -= 1
        return threading.current_thread().name

    names = each(work, range(6), threads=2, name="fan")
    assert all(isinstance(n, str) and n.startswith("fan") for n in names), names
    assert most[0] == 2


def test_one_item_runs_on_the_callers_thread() -> None:
    assert each(lambda _: threading.current_thread().name, ["x"], threads=8) \
        == [threading.current_thread().name]
