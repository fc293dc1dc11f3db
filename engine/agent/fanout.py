"""Work over many items at once, from a few threads, each item with its own outcome.

The agent does many things at the same time that may each fail alone: it spawns the brokers of a
batch (a spawn waits for its child's exec), runs the health checks of the brokers that listen (a
check is a client's round trip) and runs the lanes of ``POST /v1/batch`` (a lane may wait for a
broker of its own). :func:`each` is that one pattern: the caller says how many threads, and gets,
in order, each item's result or the exception it raised, so one failure stops none of the others.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

T = TypeVar("T")
R = TypeVar("R")


def each(work: Callable[[T], R], items: Iterable[T], *, threads: int,
         pool: ThreadPoolExecutor | None = None, name: str = "each") -> list[R | Exception]:
    """``work`` of every item, from up to ``threads`` threads named ``name`` (``pool``'s, if
    given: a loop that calls this often keeps one); each its result or its error, in order. One
    item runs on the caller's thread."""
    todo = list(items)

    def one(item: T) -> R | Exception:
        try:
            return work(item)
        except Exception as exc:  # noqa: BLE001 - this item's own error
            return exc

    if len(todo) <= 1:
        return [one(item) for item in todo]
    if pool is not None:
        return list(pool.map(one, todo))
    with ThreadPoolExecutor(max_workers=min(len(todo), threads), thread_name_prefix=name) as fresh:
        return list(fresh.map(one, todo))
