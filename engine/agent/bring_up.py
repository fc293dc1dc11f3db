"""Many brokers of one agent brought up or torn down in one step: the work behind
``BrokerManager.put_many`` and ``delete_many`` (and the wait of every single PUT and start).

A plant's apply changes many brokers of an agent at once (``POST /v1/batch``). One after another,
N brokers take N times as long as one to start or to stop; from a thread each, N threads would
poll against each other for the GIL and the CPUs. So a batch here:

- takes the brokers' operation locks in id order (two batches sharing brokers cannot deadlock);
- to start them, begins each PUT (render, spawn) from a few threads (a spawn waits for its
  child's exec), then awaits all the spawned ones in one polling loop (:func:`wait_all_healthy`);
- to delete them, stops every process together (SIGTERM to all before it waits for any), then
  moves each folder away;
- once they are healthy, lets each driver that must (:class:`~engine.drivers.base.Settling`: a
  closed Kafka cluster's lead) wait until what its broker set is in force on the other nodes;
- answers each broker alone, in order: one that fails fails alone, as its single request would.

The manager stays the owner of what this touches: its broker table and lock, each broker's fields
and folder, and what a single PUT or DELETE does to one broker. It hands this module those steps
as :class:`Steps`; this module only orders them and waits.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Generic, Protocol, TypeVar

from engine import netutil
from engine.agent.fanout import each
from engine.agent.folder import BrokerFolder
from engine.agent.owners import Owners, claim
from engine.agent.procs import BrokerProcess, log_end
from engine.drivers.base import Driver, Settling, log_file
from engine.drivers.registry import DriverRegistry
from engine.errors import BrokerUnavailableError, ProcessError
from engine.model import BrokerSpec, BrokerStatus, ObservedBroker

#: Seconds between polls of a starting broker's port, at first.
READY_POLL = 0.00025
#: Past its first moments, a starting broker's port is polled every ``elapsed / READY_BACKOFF`` s
#: (at most its health-check interval): a poll then adds at most 1/50 to the wait, and a broker
#: that takes seconds to listen is not polled 4,000 times a second. (Three agents doing that
#: while three Kafka JVMs booted on two cores slowed the JVMs: benchmarks.bench_kafka_cluster.)
READY_BACKOFF = 50.0
#: Threads that render and spawn the brokers of one put_many (a spawn waits for its child's exec),
#: and that run the health checks of those that listen.
SPAWN_THREADS = 8


class Broker(Protocol):
    """A broker as the manager keeps it, as far as a batch reads it."""

    spec: BrokerSpec
    driver: Driver | None
    folder: BrokerFolder
    op: threading.Lock
    proc: BrokerProcess | None

    def record(self) -> Owners: ...


B = TypeVar("B", bound=Broker)


@dataclass(frozen=True)
class Steps(Generic[B]):
    """What a batch may do to the manager's brokers, each step under the manager's own rules."""

    registry: DriverRegistry
    #: The broker's record (created if new) with its operation lock held.
    claim: Callable[[BrokerSpec, Driver], B]
    #: A known broker with its operation lock held, or None.
    held: Callable[[str], B | None]
    #: A PUT up to its wait (the lock held): True if the broker must now be awaited.
    begin: Callable[[B, BrokerSpec, str | None], bool]
    observe: Callable[[B], ObservedBroker]
    #: ``update(b, **fields)``: set a broker's fields under the manager's lock.
    update: Callable[..., None]
    #: Stop the brokers' processes together; the errors by broker id.
    stop: Callable[[list[B]], dict[str, Exception]]
    #: Move a stopped broker's folder away and drop it from the table.
    remove: Callable[[B], None]


def put_many(steps: Steps[B], requests: Sequence[tuple[BrokerSpec, str | None]],
             ) -> list[ObservedBroker | Exception]:
    """Make each broker run as its spec says (``(spec, owner)``, distinct ids): each is checked,
    rendered and spawned, then all are awaited in one polling loop, then settled (a driver that
    is :class:`Settling`). Each its own answer or error, in order."""
    ids = [spec.id for spec, _ in requests]
    if len(set(ids)) != len(ids):
        raise ValueError(f"put_many takes distinct broker ids, not {ids}")
    claimed: dict[str, B] = {}
    results: list[ObservedBroker | Exception | None] = [None] * len(requests)
    try:
        for i in sorted(range(len(requests)), key=lambda i: ids[i]):  # the locks in id order
            spec = requests[i][0]
            try:
                driver = steps.registry.get(spec.kind)
                driver.validate(spec)
            except Exception as exc:  # noqa: BLE001 - this broker's own error
                results[i] = exc
                continue
            claimed[spec.id] = steps.claim(spec, driver)
        todo = [i for i in range(len(requests)) if ids[i] in claimed]
        begun = each(lambda i: steps.begin(claimed[ids[i]], *requests[i]), todo,
                     threads=SPAWN_THREADS, name="spawn")
        waiting = [i for i, outcome in zip(todo, begun) if outcome is True]
        for i, outcome in zip(todo, begun):
            if isinstance(outcome, Exception):
                results[i] = outcome
        errors = wait_all_healthy([claimed[ids[i]] for i in waiting], steps.update)
        for i, error in zip(waiting, errors):
            if error is not None:
                results[i] = error
        settling = [i for i in todo if results[i] is None and isinstance(claimed[ids[i]].driver, Settling)]
        settled = each(lambda i: claimed[ids[i]].driver.settle(claimed[ids[i]].spec),  # type: ignore[union-attr]
                       settling, threads=SPAWN_THREADS, name="settle")
        for i, outcome in zip(settling, settled):
            if isinstance(outcome, Exception):
                results[i] = outcome
        for i in todo:
            if results[i] is None:
                results[i] = steps.observe(claimed[ids[i]])
    finally:
        for b in claimed.values():
            b.op.release()
    return [r for r in results if r is not None]


def delete_many(steps: Steps[B], requests: Sequence[tuple[str, str | None]]) -> list[Exception | None]:
    """Stop and remove each broker (``(broker id, owner)``, distinct ids; an unknown one is
    already gone): every process is sent SIGTERM, then all are waited for, then the folders are
    moved away. Each its own error (None: deleted), in order."""
    ids = [broker_id for broker_id, _ in requests]
    if len(set(ids)) != len(ids):
        raise ValueError(f"delete_many takes distinct broker ids, not {ids}")
    errors: list[Exception | None] = [None] * len(requests)
    held: list[tuple[int, B]] = []
    try:
        for i in sorted(range(len(requests)), key=lambda i: ids[i]):  # the locks in id order
            b = steps.held(ids[i])
            if b is None:
                continue
            held.append((i, b))
            try:
                claim(b.record().owner, requests[i][1], f"broker {ids[i]!r}")
            except Exception as exc:  # noqa: BLE001 - this broker's own error
                errors[i] = exc
        going = [(i, b) for i, b in held if errors[i] is None]
        stopped = steps.stop([b for _, b in going if b.proc is not None])
        for i, b in going:
            if stopped.get(b.spec.id) is not None:
                errors[i] = stopped[b.spec.id]
                continue
            try:
                steps.remove(b)
            except Exception as exc:  # noqa: BLE001 - this broker's own error
                errors[i] = exc
    finally:
        for _, b in held:
            b.op.release()
    return errors


@dataclass(eq=False)
class _Waiting:
    """A broker being awaited by :func:`wait_all_healthy`: its poll state."""

    b: Broker
    began: float                           # monotonic, when the wait began
    deadline: float                        # monotonic
    slow: float                            # seconds between health checks once it listens
    listening: bool = False
    next_poll: float = 0.0


def wait_all_healthy(brokers: Sequence[Broker], update: Callable[..., None]) -> list[Exception | None]:
    """Poll every spawned broker in one loop until it passes the driver's health check (RUNNING),
    exits (FAILED, ProcessError) or passes its start deadline (BrokerUnavailableError); each
    one's error (None: healthy), in order. ``update(b, **fields)`` records its status.

    Until a broker's port accepts TCP connections, only that is polled, every ``READY_POLL``
    s at first (a refused connect costs microseconds; Mosquitto listens ~6 ms after spawn, and
    every poll interval of slack was added to each deployment), less often as the wait grows
    (:func:`poll_interval`); then the driver's own check, at most every 1/5000 of its start
    deadline (Mosquitto 2 ms, Kafka's 90 s -> 18 ms). One loop
    for N brokers: N threads each polling would fight over the GIL and the CPUs."""
    start = time.monotonic()
    waits = [_Waiting(b, start, start + b.driver.start_deadline, min(0.25, b.driver.start_deadline / 5000))
             for b in brokers if b.driver is not None]
    assert len(waits) == len(brokers) and all(b.proc is not None for b in brokers)
    errors: dict[int, Exception | None] = {}
    with ThreadPoolExecutor(max_workers=SPAWN_THREADS, thread_name_prefix="health") as pool:
        _poll_all(waits, errors, pool, update)
    return [errors[i] for i in range(len(waits))]


def _poll_all(waits: list[_Waiting], errors: dict[int, Exception | None], pool: ThreadPoolExecutor,
              update: Callable[..., None]) -> None:
    """The loop of :func:`wait_all_healthy`: fills ``errors`` for every broker."""
    while len(errors) < len(waits):
        due = [i for i, w in enumerate(waits) if i not in errors and time.monotonic() >= w.next_poll]
        # Process and port of each (microseconds), then the health checks of those listening
        # from a few threads (a check is a client's round trip; Kafka's may take a second).
        listening = []
        for i in due:
            try:
                if _poll_port(waits[i]):
                    listening.append(i)
            except ProcessError as exc:
                update(waits[i].b, proc=None, status=BrokerStatus.FAILED, last_error=exc.message)
                errors[i] = exc
        checks = each(lambda i: waits[i].b.driver.health(waits[i].b.spec, 1.0),  # type: ignore[union-attr]
                      listening, threads=SPAWN_THREADS, pool=pool)
        for i, healthy in zip(listening, checks):
            if isinstance(healthy, Exception):  # its single PUT would have raised it too
                errors[i] = healthy
            elif healthy:
                update(waits[i].b, status=BrokerStatus.RUNNING, healthy_since=time.monotonic())
                errors[i] = None
        now = time.monotonic()
        for i in due:
            w = waits[i]
            if i in errors:
                continue
            if now >= w.deadline:
                errors[i] = _still_starting(w.b, update)
            else:
                w.next_poll = now + poll_interval(now - w.began, w.listening, w.slow)
        pending = [w.next_poll for i, w in enumerate(waits) if i not in errors]
        if pending:
            pause = min(pending) - time.monotonic()
            if pause > 0:
                time.sleep(pause)


def poll_interval(elapsed: float, listening: bool, slow: float) -> float:
    """Seconds until a starting broker is polled again, ``elapsed`` s into the wait: its health
    check every ``slow`` s once it listens; before that its port, every :data:`READY_POLL` s while
    a quick broker would come up (Mosquitto listens ~6 ms after spawn), then every
    ``elapsed / READY_BACKOFF`` s, never more than ``slow``."""
    if listening:
        return slow
    return min(slow, max(READY_POLL, elapsed / READY_BACKOFF))


def _poll_port(w: _Waiting) -> bool:
    """Whether a starting broker's port accepts connections (then it is due a health check);
    ProcessError if its process is gone."""
    b = w.b
    driver, spec, proc = b.driver, b.spec, b.proc
    assert driver is not None and proc is not None
    if not proc.alive():
        code = proc.exit_code()
        raise ProcessError(
            f"broker {spec.id!r} ({driver.kind}) exited"
            + (f" with code {code}" if code is not None else "")
            + f" while starting; log {log_file(b.folder.path, driver.kind)} ends with:\n"
            + log_end(proc)
        )
    if not w.listening:
        w.listening = netutil.port_open(spec.host, spec.port, timeout=0.05)
    return w.listening


def _still_starting(b: Broker, update: Callable[..., Any]) -> BrokerUnavailableError:
    assert b.driver is not None
    message = (f"broker {b.spec.id!r} ({b.driver.kind}) did not answer its health check "
               f"within {b.driver.start_deadline:.0f} s")
    update(b, last_error=message)
    return BrokerUnavailableError(
        f"broker {b.spec.id!r} is still starting after {b.driver.start_deadline:.0f} s",
        hint="PUT it again to keep waiting; see its log "
        f"{log_file(b.folder.path, b.driver.kind)}",
    )
