"""The supervision loop the agent runs for its brokers and for its bridge workers.

One daemon thread per manager calls ``step(unit)`` for every unit every ``tick`` seconds. A unit
whose operation lock is held (a PUT or DELETE in progress) is skipped this round rather than
waited for, so supervision never queues behind a slow start; an exception in one unit's step is
logged and the loop goes on, because the supervisor must outlive any one broker or worker.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Iterable
from typing import Protocol, TypeVar

log = logging.getLogger(__name__)


class Supervised(Protocol):
    """What the loop needs of a unit: its operation lock."""

    op: threading.Lock


U = TypeVar("U", bound=Supervised)


def backoff(base: float, cap: float, failures: int) -> float:
    """Seconds before restart number ``failures`` (1-based): doubling from ``base`` up to ``cap``."""
    return min(cap, base * 2 ** max(failures - 1, 0))


def start_supervisor(name: str, stop: threading.Event, tick: float, units: Callable[[], Iterable[U]],
                     step: Callable[[U], None], describe: Callable[[U], str]) -> threading.Thread:
    """Start the loop on a daemon thread; it ends once ``stop`` is set (join the thread)."""
    def loop() -> None:
        while not stop.wait(tick):
            for unit in units():
                if stop.is_set() or not unit.op.acquire(blocking=False):
                    continue
                try:
                    step(unit)
                except Exception:  # noqa: BLE001 - see the module docstring
                    log.exception("supervising %s", describe(unit))
                finally:
                    unit.op.release()

    thread = threading.Thread(target=loop, name=name, daemon=True)
    thread.start()
    return thread
