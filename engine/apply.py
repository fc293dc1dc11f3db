"""Apply a plan: send its changes to the agents, in parallel where order allows, then check.

Every pending change becomes one or two agent calls (:func:`operations`). Calls are grouped in
*lanes*, one per broker: a lane runs in plan order (the broker before its topics, topic deletes
before the broker's delete), lanes run in parallel (``parallelism`` threads). A lane whose broker
takes over an address (host, port) another broker frees joins that broker's lane after it, so the
old broker is gone before the new one binds.

A :class:`TemporaryDispatchError` is retried with exponential backoff and jitter while the
change's deadline lasts; a :class:`PermanentDispatchError` (or a temporary one that outlived its
deadline) fails the change and skips the rest of its lane; other lanes go on.

Afterwards the agents are asked again and the plan is made again: it must be empty. A change that
an agent reported as done but that still shows up is the agent's (driver's) fault and is reported
as an *unexpected result* (Terraform: "provider produced an unexpected new value"). Since every
call is idempotent, running apply again picks up whatever failed.
"""

from __future__ import annotations

import random
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from enum import Enum
from typing import Any, Protocol

from engine.agents_config import AgentDirectory, AgentsConfigError
from engine.errors import DispatchError, EngineError, TemporaryDispatchError
from engine.model import Action, BridgeMechanism, Change, DesiredState, ObservedState, Plan
from engine.observed import observe
from engine.plan import ALL_TOPIC_SETTINGS, NEW_BROKER_FIELDS, broker_of, destroy_plan, topic_settings
from engine.plan import plan as make_plan
from kg.errors import PlantKGError


class PlanNotApplicableError(EngineError):
    """The plan has refusals or unreachable hosts: nothing is dispatched."""

    def __init__(self, plan: Plan) -> None:
        why = [f"{r.address}: {r.reason}" for r in plan.refusals]
        why += [f"the agent of {host} did not answer" for host in plan.unreachable]
        super().__init__("the plan cannot be applied:\n  " + "\n  ".join(why),
                         hint="change the plant (refusals) or start the agents (unreachable), "
                              "then plan again")
        self.plan = plan


# ------------------------------------------------------------------------------------ settings

@dataclass(frozen=True)
class RetryPolicy:
    """Retries of temporary failures: exponential backoff with jitter, bounded by a deadline."""

    attempts: int = 8            # at most this many calls per agent request
    base: float = 0.5            # first delay (s)
    cap: float = 15.0            # longest delay (s)
    deadline: float = 300.0      # give up retrying a change after this many seconds

    def delay(self, attempt: int, rng: random.Random) -> float:
        """Seconds to wait after failed attempt number ``attempt`` (1-based): full jitter on half."""
        step = min(self.cap, self.base * 2 ** (attempt - 1))
        return step * (0.5 + rng.random() / 2)


class Clock(Protocol):
    def __call__(self) -> float: ...


# ------------------------------------------------------------------------------------- results

class EventKind(str, Enum):
    START = "start"
    DONE = "done"
    RETRY = "retry"
    FAILED = "failed"
    SKIPPED = "skipped"
    VERIFY = "verify"


@dataclass(frozen=True)
class ApplyEvent:
    """Progress for people: a change started, finished, is retried, failed or was skipped."""

    kind: EventKind
    address: str
    action: Action
    elapsed: float = 0.0
    attempt: int = 1
    message: str = ""


class OutcomeStatus(str, Enum):
    DONE = "done"
    FAILED = "failed"
    SKIPPED = "skipped"


@dataclass(frozen=True)
class Outcome:
    """What became of one change."""

    change: Change
    status: OutcomeStatus
    seconds: float = 0.0
    attempts: int = 0
    error: str | None = None


@dataclass(frozen=True)
class Unexpected:
    """A difference left after apply that the agents should have removed."""

    address: str
    detail: str


@dataclass(frozen=True)
class ApplyResult:
    """Changes made, failed and skipped; the plan made again afterwards; time taken."""

    plan: Plan
    outcomes: tuple[Outcome, ...]
    after: Plan | None = None
    unexpected: tuple[Unexpected, ...] = ()
    seconds: float = 0.0

    def _with(self, status: OutcomeStatus) -> tuple[Outcome, ...]:
        return tuple(o for o in self.outcomes if o.status is status)

    @property
    def changed(self) -> tuple[Outcome, ...]:
        return self._with(OutcomeStatus.DONE)

    @property
    def failed(self) -> tuple[Outcome, ...]:
        return self._with(OutcomeStatus.FAILED)

    @property
    def skipped(self) -> tuple[Outcome, ...]:
        return self._with(OutcomeStatus.SKIPPED)

    @property
    def converged(self) -> bool:
        """True when the plan made after apply has nothing left to do and could be made."""
        return self.after is not None and self.after.empty and self.after.applicable

    @property
    def ok(self) -> bool:
        return not self.failed and not self.skipped and not self.unexpected and self.converged


# -------------------------------------------------------------------------------- operations

@dataclass(frozen=True)
class Call:
    """One request to one agent: ``verb`` is an AgentClient method, ``args`` its arguments."""

    host: str
    verb: str
    args: tuple[Any, ...]
    #: put_bridge of an mqtt-ngsi bridge, or of an mqtt-kafka bridge into a closed Kafka: the host
    #: whose agent's token goes along as the remote token (the context broker's write token; the
    #: agent derives plantkg's Kafka password from it), looked up only when the call is made, so no
    #: token is ever part of a plan, an operation or an event.
    remote_token_of: str | None = None
    #: the plant that owns what the call makes or deletes (DesiredState.owner): the agent records
    #: it and refuses another plant's things. None: no owner is sent (a plant without one).
    owner: str | None = None


@dataclass(frozen=True)
class Operation:
    """A change and the agent calls that make it, in order."""

    change: Change
    calls: tuple[Call, ...]


def operations(plan: Plan, desired: DesiredState) -> list[Operation]:
    """The agent calls of each pending change."""
    deleted_hosts = {
        broker_of(c): str(c.before["host"])
        for c in plan.pending
        if c.action is Action.DELETE and c.address.startswith("broker.") and c.before
    }

    def host_of(broker_id: str) -> str:
        if broker_id in deleted_hosts:
            return deleted_hosts[broker_id]
        spec = desired.broker(broker_id)
        if spec is None:
            raise EngineError(f"the plan names broker {broker_id!r}, which the plant does not",
                              hint="make the plan again from the same plant")
        return spec.host

    out: list[Operation] = []
    for change in plan.pending:
        kind = change.address.split(".", 1)[0]
        if kind == "broker":
            calls = _broker_calls(change, desired)
        elif kind == "topic":
            calls = _topic_calls(change, desired, host_of)
        else:
            calls = _bridge_calls(change, desired)
        out.append(Operation(change, tuple(replace(c, owner=desired.owner) for c in calls)))
    return out


def _broker_calls(change: Change, desired: DesiredState) -> tuple[Call, ...]:
    broker_id = broker_of(change)
    if change.action is Action.DELETE:
        assert change.before is not None
        return (Call(str(change.before["host"]), "delete_broker", (broker_id,)),)
    spec = desired.broker(broker_id)
    if spec is None:
        raise EngineError(f"the plan creates broker {broker_id!r}, which the plant does not describe",
                          hint="make the plan again from the same plant")
    put = Call(spec.host, "put_broker", (spec,))
    if change.action is Action.REPLACE and change.before is not None and any(
        change.before[f] != change.after[f] for f in NEW_BROKER_FIELDS  # type: ignore[index]
    ):
        return (Call(str(change.before["host"]), "delete_broker", (broker_id,)), put)
    return (put,)


def _topic_calls(change: Change, desired: DesiredState, host_of: Callable[[str], str]) -> tuple[Call, ...]:
    broker_id = broker_of(change)
    if change.action is Action.DELETE:
        assert change.before is not None
        return (Call(host_of(broker_id), "delete_topic", (broker_id, str(change.before["name"]))),)
    spec = next((t for t in desired.topics if t.address == change.address), None)
    broker = desired.broker(broker_id)
    if spec is None or broker is None:
        raise EngineError(f"the plan creates {change.address}, which the plant does not describe",
                          hint="make the plan again from the same plant")
    # Only the settings of the broker's kind travel (a driver refuses another kind's settings).
    applicable = topic_settings(broker.kind)
    spec = replace(spec, **{f: None for f in ALL_TOPIC_SETTINGS if f not in applicable})
    return (Call(host_of(broker_id), "put_topic", (spec,)),)


def _bridge_calls(change: Change, desired: DesiredState) -> tuple[Call, ...]:
    """A bridge is PUT to (or deleted from) the agent of its local broker."""
    if change.action is Action.DELETE:
        assert change.before is not None
        local, remote = change.before["local"], change.before["remote"]
        return (Call(str(local["host"]), "delete_bridge", (str(local["id"]), str(remote["id"]))),)
    spec = next((b for b in desired.bridges if b.address == change.address), None)
    if spec is None:
        raise EngineError(f"the plan creates {change.address}, which the plant does not describe",
                          hint="make the plan again from the same plant")
    remote = desired.broker(spec.remote.id)
    closed_kafka = spec.mechanism is BridgeMechanism.WORKER and remote is not None and bool(remote.users)
    if spec.mechanism is BridgeMechanism.NGSI or closed_kafka:  # the worker logs in on the remote
        return (Call(spec.local.host, "put_bridge", (spec,), remote_token_of=spec.remote.host),)
    return (Call(spec.local.host, "put_bridge", (spec,)),)


def lanes(ops: Sequence[Operation]) -> list[list[Operation]]:
    """Operations grouped per broker, in plan order; a broker that binds an address another one
    frees runs after it, in the same lane."""
    by_broker: dict[str, list[Operation]] = {}
    for op in ops:
        by_broker.setdefault(broker_of(op.change), []).append(op)
    frees: dict[tuple[Any, Any], str] = {}
    for broker_id, lane in by_broker.items():
        for op in lane:
            c = op.change
            if c.address.startswith("broker.") and c.before and c.action in (Action.DELETE, Action.REPLACE):
                frees[(c.before["host"], c.before["port"])] = broker_id
    order = list(by_broker)
    merged: dict[str, list[Operation]] = {b: list(by_broker[b]) for b in order}
    home = {b: b for b in order}
    for broker_id in order:
        for op in by_broker[broker_id]:
            c = op.change
            if not (c.address.startswith("broker.") and c.after
                    and c.action in (Action.CREATE, Action.REPLACE)):
                continue
            other = frees.get((c.after["host"], c.after["port"]))
            if other is None or home[other] == home[broker_id]:
                continue
            src, dst = home[other], home[broker_id]
            merged[dst] = merged.pop(src) + merged[dst]
            home = {b: (dst if h == src else h) for b, h in home.items()}
    for nodes in _rolling(ops):  # a running cluster's nodes restart one at a time
        dst = home[nodes[0]]
        for node in nodes[1:]:
            src = home[node]
            if src != dst:
                merged[dst] = merged[dst] + merged.pop(src)
                home = {b: (dst if h == src else h) for b, h in home.items()}
    return [lane for lane in merged.values() if lane]


def _rolling(ops: Sequence[Operation]) -> list[list[str]]:
    """Per Kafka cluster, its running nodes that the plan restarts (replace), by node id: their
    lanes are joined so the restarts roll one node at a time — each node's PUT returns once the
    node is back in sync (the driver's health), then the next stops. New nodes start in parallel
    (a new quorum needs its majority up at once)."""
    clusters: dict[str, list[tuple[int, str]]] = {}
    for op in ops:
        c = op.change
        if c.action is not Action.REPLACE or not c.address.startswith("broker."):
            continue
        before, after = (c.before or {}).get("kafka"), (c.after or {}).get("kafka")
        if before and after and before.get("cluster") == after.get("cluster"):
            clusters.setdefault(str(after["cluster"]), []).append((int(after["node_id"]), broker_of(c)))
    return [[b for _, b in sorted(nodes)] for nodes in clusters.values() if len(nodes) > 1]


# ------------------------------------------------------------------------------------ running

@dataclass
class _Runner:
    directory: AgentDirectory
    policy: RetryPolicy
    emit: Callable[[ApplyEvent], None]
    clock: Clock
    sleep: Callable[[float], None]
    rng: random.Random
    rng_lock: threading.Lock = field(default_factory=threading.Lock)

    def run_lane(self, lane: list[Operation]) -> list[Outcome]:
        outcomes: list[Outcome] = []
        for index, op in enumerate(lane):
            outcome = self.run_operation(op)
            outcomes.append(outcome)
            if outcome.status is OutcomeStatus.FAILED:
                why = f"not attempted: {op.change.address} failed"
                for rest in lane[index + 1:]:
                    self.emit(ApplyEvent(EventKind.SKIPPED, rest.change.address, rest.change.action,
                                         message=why))
                    outcomes.append(Outcome(rest.change, OutcomeStatus.SKIPPED, error=why))
                break
        return outcomes

    def run_operation(self, op: Operation) -> Outcome:
        change = op.change
        start = self.clock()
        self.emit(ApplyEvent(EventKind.START, change.address, change.action))
        tally = [0]  # attempts so far, counted by _call_with_retries
        try:
            for call in op.calls:
                self._call_with_retries(op, call, start, tally)
        except DispatchError as exc:
            return self._failed(change, start, tally[0], exc.message + (f" ({exc.hint})" if exc.hint else ""))
        except PlantKGError as exc:
            return self._failed(change, start, tally[0], str(exc))
        except Exception as exc:  # a bug must not take the other lanes down; it is reported
            return self._failed(change, start, tally[0], f"internal error: {type(exc).__name__}: {exc}")
        elapsed = self.clock() - start
        self.emit(ApplyEvent(EventKind.DONE, change.address, change.action, elapsed, tally[0]))
        return Outcome(change, OutcomeStatus.DONE, elapsed, tally[0])

    def _failed(self, change: Change, start: float, attempts: int, error: str) -> Outcome:
        elapsed = self.clock() - start
        self.emit(ApplyEvent(EventKind.FAILED, change.address, change.action, elapsed, attempts, error))
        return Outcome(change, OutcomeStatus.FAILED, elapsed, attempts, error)

    def _call_with_retries(self, op: Operation, call: Call, start: float, tally: list[int]) -> None:
        """Make ``call``, retrying temporary failures; ``tally[0]`` counts every attempt."""
        attempt = 0
        while True:
            attempt += 1
            tally[0] += 1
            try:
                client = self.directory.client_for(call.host)
                extra: dict[str, Any] = {} if call.owner is None else {"owner": call.owner}
                if call.remote_token_of is not None:
                    extra["remote_token"] = _token_of(self.directory, call.remote_token_of)
                getattr(client, call.verb)(*call.args, **extra)
                return
            except TemporaryDispatchError as exc:
                with self.rng_lock:
                    delay = self.policy.delay(attempt, self.rng)
                spent = self.clock() - start
                if attempt >= self.policy.attempts or spent + delay > self.policy.deadline:
                    raise TemporaryDispatchError(
                        f"{exc.message} (gave up after {attempt} attempt(s), {spent:.1f} s)",
                        hint=exc.hint or "check that the agent runs and answers, then apply again",
                        host=call.host) from exc
                self.emit(ApplyEvent(EventKind.RETRY, op.change.address, op.change.action,
                                     spent, attempt, f"{exc.message}; retrying in {delay:.1f} s"))
                self.sleep(delay)


def _token_of(directory: AgentDirectory, host: str) -> str | None:
    """The token of the agent at ``host`` (which a context broker there takes for writes), or
    None if the engine knows none: the bridge then writes without one (an open context broker)."""
    try:
        return directory.token_for(host)
    except AgentsConfigError:
        return None


def apply(
    plan: Plan,
    desired: DesiredState,
    directory: AgentDirectory,
    *,
    parallelism: int = 8,
    retries: RetryPolicy = RetryPolicy(),
    on_event: Callable[[ApplyEvent], None] | None = None,
    destroy: bool = False,
    hosts: Iterable[str] | None = None,
    observe_fn: Callable[[AgentDirectory, Iterable[str]], ObservedState] = observe,
    clock: Clock = time.monotonic,
    sleep: Callable[[float], None] = time.sleep,
    rng: random.Random | None = None,
    prune: bool = False,
) -> ApplyResult:
    """Dispatch ``plan`` (made from ``desired``) to the agents, then check it converged.

    ``destroy``: the plan came from :func:`engine.plan.destroy_plan`; the check re-plans that way.
    ``on_event`` is called for every start, finish, retry, failure and skip (one call at a time).
    ``hosts``: the agents to ask again afterwards (default: every host the plan or plant names,
    and the agents file's). ``prune``: the plan was made with ``prune`` (the check re-plans so).
    Every call names ``desired.owner``, so an agent refuses to touch another plant's things.
    """
    if not plan.applicable:
        raise PlanNotApplicableError(plan)
    lock = threading.Lock()

    def emit(event: ApplyEvent) -> None:
        if on_event is not None:
            with lock:
                on_event(event)

    began = clock()
    runner = _Runner(directory, retries, emit, clock, sleep, rng or random.Random())
    work = lanes(operations(plan, desired))
    outcomes: list[Outcome] = []
    if work:
        with ThreadPoolExecutor(max_workers=max(1, min(parallelism, len(work))),
                                thread_name_prefix="apply") as pool:
            for lane_outcomes in pool.map(runner.run_lane, work):
                outcomes.extend(lane_outcomes)
    order = {c.address: i for i, c in enumerate(plan.changes)}
    outcomes.sort(key=lambda o: order.get(o.change.address, len(order)))
    ask = set(hosts) if hosts is not None else _hosts(plan, desired, directory)
    emit(ApplyEvent(EventKind.VERIFY, "plan", Action.NOOP, message="asking the agents again"))
    try:
        observed = observe_fn(directory, ask)
    except PlantKGError as exc:  # the changes are made; say what is known, and why no check
        problem = Unexpected("check", f"could not ask the agents again: {exc}")
        return ApplyResult(plan, tuple(outcomes), None, (problem,), clock() - began)
    after = destroy_plan(desired, observed) if destroy else make_plan(desired, observed, prune=prune)
    return ApplyResult(plan, tuple(outcomes), after, tuple(unexpected(plan, outcomes, after)),
                       clock() - began)


def _hosts(plan: Plan, desired: DesiredState, directory: AgentDirectory) -> set[str]:
    found = {b.host for b in desired.brokers} | set(directory.hosts)
    for change in plan.changes:
        for data in (change.before, change.after):
            if data and "host" in data:
                found.add(str(data["host"]))
    return found


def unexpected(plan: Plan, outcomes: Sequence[Outcome], after: Plan) -> list[Unexpected]:
    """Differences left after apply that no failure explains: the drivers' fault."""
    done = {o.change.address for o in outcomes if o.status is OutcomeStatus.DONE}
    planned = {c.address for c in plan.pending}
    out = []
    for change in after.pending:
        if change.address in done:
            out.append(Unexpected(change.address,
                                  f"the agent reported the {_noun(change)} done, but it still "
                                  f"needs {change.action.value}: {change.reason or 'differs'}"))
        elif change.address not in planned:
            out.append(Unexpected(change.address,
                                  f"changed while applying (now needs {change.action.value}: "
                                  f"{change.reason or 'differs'})"))
    for refusal in after.refusals:
        out.append(Unexpected(refusal.address, f"after apply: {refusal.reason}"))
    for host in after.unreachable:
        out.append(Unexpected(host, "the agent did not answer after apply"))
    return out


def _noun(change: Change) -> str:
    return change.address.split(".", 1)[0]
