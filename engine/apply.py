"""Apply a plan: send its changes to the agents, in batches, in parallel where order allows, then
check.

Every pending change becomes one or two agent calls, grouped in *lanes*, one per broker
(:mod:`engine.apply_calls`): a lane runs in plan order, lanes are independent. The calls go out
in *waves*: each wave sends every agent one request (``POST /v1/batch``) with the next calls of
every lane ready for it, over a connection kept open; the agent runs the lanes at the same time
(N brokers start, and are awaited, together) and answers a result per call. A lane whose next
call is for another agent (a broker moving host) continues there in the next wave. Agents are
asked in parallel (``parallelism`` requests at a time).

A :class:`TemporaryDispatchError` (the agent unreachable, a 503, a 5xx) is retried with
exponential backoff and jitter while the change's deadline lasts, from the call that failed; a
:class:`PermanentDispatchError` (or a temporary one that outlived its deadline) fails the change
and skips the rest of its lane; other lanes go on. Events report each change as before: started,
done, retried, failed, skipped.

Afterwards the plan is made again from what the agents run: it must be empty. An agent that
answered the last wave it took part in with its state (``observe``) is not asked again; the others
are. A change that an agent reported as done but that still shows up is the agent's (driver's)
fault and is reported as an *unexpected result* (Terraform: "provider produced an unexpected new
value"). Since every call is idempotent, running apply again picks up whatever failed.
"""

from __future__ import annotations

import random
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, Protocol

from engine.agent.calls import AgentCall, BatchAnswer, CallResult, run_calls
from engine.agents_config import AgentDirectory, AgentsConfigError
from engine.apply_calls import Call, Operation, lanes, operations
from engine.errors import DispatchError, EngineError, TemporaryDispatchError
from engine.model import Action, Change, DesiredState, ObservedBridge, ObservedBroker, ObservedState, Plan
from engine.observed import observe
from engine.plan import destroy_plan
from engine.plan import plan as make_plan
from kg.errors import PlantKGError

__all__ = ["apply", "ApplyResult", "ApplyEvent", "EventKind", "Outcome", "OutcomeStatus", "RetryPolicy",
           "PlanNotApplicableError", "Unexpected", "Call", "Operation", "lanes", "operations"]

#: At most this many calls of one lane go in one wave (the rest in the next).
MAX_WAVE_CALLS = 256


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


# ------------------------------------------------------------------------------------ running

@dataclass(eq=False)
class _Lane:
    """A lane being run: its calls in order, flattened, and where it stands."""

    ops: list[Operation]
    steps: list[tuple[int, Call]]          # (index of its operation, call)
    cursor: int = 0                        # the next step to make
    attempt: int = 0                       # failed attempts of that step so far
    ready_at: float = 0.0                  # not before (a backoff)
    started: dict[int, float] = field(default_factory=dict)   # operation -> clock at its start
    tally: dict[int, int] = field(default_factory=dict)       # operation -> calls attempted
    outcomes: list[Outcome] = field(default_factory=list)
    finished: bool = False

    #: operation -> the operations without calls its calls make too (engine.apply_calls: a
    #: deleted broker's topics); they start, end and fail with it.
    carried: dict[int, list[int]] = field(default_factory=dict)

    @classmethod
    def of(cls, ops: list[Operation]) -> _Lane:
        lane = cls(ops, [(i, call) for i, op in enumerate(ops) for call in op.calls])
        where = {op.change.address: i for i, op in enumerate(ops) if op.calls}
        for i, op in enumerate(ops):
            if op.carried_by is None:
                continue
            if op.carried_by not in where:  # apply_calls puts a broker's topics in its lane
                raise AssertionError(f"{op.change.address} is carried by {op.carried_by}, "
                                     "which is not in its lane")
            lane.carried.setdefault(where[op.carried_by], []).append(i)
        return lane

    def wave(self) -> list[tuple[int, Call]]:
        """The next calls to send together: from the cursor, while they go to the same host."""
        first = self.steps[self.cursor][1].host
        out = []
        for step in self.steps[self.cursor:self.cursor + MAX_WAVE_CALLS]:
            if step[1].host != first:
                break
            out.append(step)
        return out


@dataclass(eq=False)
class _Request:
    """One batch in flight: to which agent, which lanes with which calls."""

    agent: int                              # id of the client
    parts: list[tuple[_Lane, list[tuple[int, Call]]]]
    overlapped: bool = False                # another request to the agent was in flight meanwhile


@dataclass
class _Runner:
    directory: AgentDirectory
    policy: RetryPolicy
    emit: Callable[[ApplyEvent], None]
    clock: Clock
    sleep: Callable[[float], None]
    rng: random.Random
    parallelism: int = 8
    #: per agent (id of its client): the state its last answer reported, when that answer is known
    #: to be the agent's state after all of this apply's calls to it (else None).
    states: dict[int, tuple[tuple[ObservedBroker, ...], tuple[ObservedBridge, ...]] | None] = \
        field(default_factory=dict)
    clients: dict[int, Any] = field(default_factory=dict)

    def run(self, work: list[list[Operation]]) -> list[Outcome]:
        """Run every lane to its end (done, failed or skipped); their outcomes."""
        todo = [_Lane.of(lane) for lane in work]
        flying: dict[Future[BatchAnswer], _Request] = {}
        busy: set[_Lane] = set()
        with ThreadPoolExecutor(max_workers=max(1, self.parallelism), thread_name_prefix="apply") as pool:
            while True:
                for request in self._next_wave([ln for ln in todo if not ln.finished and ln not in busy]):
                    for other in flying.values():
                        if other.agent == request.agent:
                            other.overlapped = request.overlapped = True
                    client = self.clients[request.agent]
                    calls = [[self._agent_call(call) for _, call in part] for _, part in request.parts]
                    batch = getattr(client, "batch", None)
                    flying[pool.submit(batch, calls, observe=True) if batch is not None  # an agent
                           else pool.submit(run_calls, client, calls)] = request  # a client with verbs only
                    busy.update(lane for lane, _ in request.parts)
                waiting = [ln for ln in todo if not ln.finished and ln not in busy]
                if not flying:
                    if not waiting:
                        break
                    self.sleep(max(0.0, min(ln.ready_at for ln in waiting) - self.clock()))
                    continue
                timeout = None
                if waiting:
                    timeout = max(0.0, min(ln.ready_at for ln in waiting) - self.clock())
                finished, _ = wait(list(flying), timeout=timeout, return_when=FIRST_COMPLETED)
                for future in finished:
                    request = flying.pop(future)
                    busy.difference_update(lane for lane, _ in request.parts)
                    self._settle(request, future)
        return [o for lane in todo for o in lane.outcomes]

    def _next_wave(self, lanes_: list[_Lane]) -> list[_Request]:
        """One request per agent with the next calls of every lane ready now."""
        now = self.clock()
        by_agent: dict[int, _Request] = {}
        for lane in lanes_:
            if lane.ready_at > now:
                continue
            part = lane.wave()
            try:
                client = self.directory.client_for(part[0][1].host)
            except PlantKGError as exc:  # no agent or token known for the host
                self._start_ops(lane, part[:1])
                self._fail(lane, part[0][0], str(exc), attempts_add=1)
                continue
            self._start_ops(lane, part)
            key = id(client)
            self.clients[key] = client
            by_agent.setdefault(key, _Request(key, [])).parts.append((lane, part))
        return list(by_agent.values())

    def _start_ops(self, lane: _Lane, part: list[tuple[int, Call]]) -> None:
        for index, _ in part:
            for started in (*lane.carried.get(index, ()), index):
                if started not in lane.started:
                    lane.started[started] = self.clock()
                    change = lane.ops[started].change
                    self.emit(ApplyEvent(EventKind.START, change.address, change.action))

    def _agent_call(self, call: Call) -> AgentCall:
        token = _token_of(self.directory, call.remote_token_of) if call.remote_token_of else None
        return AgentCall(call.verb, call.args, owner=call.owner, remote_token=token)

    def _settle(self, request: _Request, future: Future[BatchAnswer]) -> None:
        """Take a request's answer (or its failure) into its lanes."""
        try:
            answer = future.result()
        except DispatchError as exc:
            self.states[request.agent] = None
            for lane, part in request.parts:
                self._step_failed(lane, part[0][0], exc)
            return
        except Exception as exc:  # noqa: BLE001 - a bug must not take the other lanes down
            self.states[request.agent] = None
            for lane, part in request.parts:
                self._fail(lane, part[0][0], f"internal error: {type(exc).__name__}: {exc}", attempts_add=1)
            return
        self.states[request.agent] = (
            (answer.brokers, answer.bridges)  # type: ignore[assignment]
            if answer.observed and not request.overlapped else None)
        for (lane, part), results in zip(request.parts, answer.lanes):
            self._take(lane, part, results)

    def _take(self, lane: _Lane, part: list[tuple[int, Call]], results: Sequence[CallResult]) -> None:
        if results and results[0].skipped:  # an agent that skips a lane without a failure
            self._fail(lane, part[0][0], "the agent skipped the call without a failure before it",
                       attempts_add=1)
            return
        for (index, _), result in zip(part, results):
            if result.done:
                lane.tally[index] = lane.tally.get(index, 0) + 1
                lane.cursor += 1
                lane.attempt = 0
                last = lane.cursor == len(lane.steps) or lane.steps[lane.cursor][0] != index
                if last:
                    for carried in lane.carried.get(index, ()):
                        lane.tally[carried] = lane.tally[index]
                        self._done(lane, carried)
                    self._done(lane, index)
                continue
            if result.error is not None:
                self._step_failed(lane, index, result.error)
            return  # the agent did not attempt the rest (skipped): they go in the next wave
        if lane.cursor == len(lane.steps):
            lane.finished = True

    def _step_failed(self, lane: _Lane, index: int, exc: DispatchError) -> None:
        """A call failed: retry it later if temporary and time is left, else fail its change."""
        lane.tally[index] = lane.tally.get(index, 0) + 1
        if not isinstance(exc, TemporaryDispatchError):
            self._fail(lane, index, exc.message + (f" ({exc.hint})" if exc.hint else ""))
            return
        lane.attempt += 1
        delay = self.policy.delay(lane.attempt, self.rng)
        change = lane.ops[index].change
        spent = self.clock() - lane.started[index]
        if lane.attempt >= self.policy.attempts or spent + delay > self.policy.deadline:
            gave_up = TemporaryDispatchError(
                f"{exc.message} (gave up after {lane.attempt} attempt(s), {spent:.1f} s)",
                hint=exc.hint or "check that the agent runs and answers, then apply again")
            self._fail(lane, index, gave_up.message + f" ({gave_up.hint})")
            return
        self.emit(ApplyEvent(EventKind.RETRY, change.address, change.action, spent, lane.attempt,
                             f"{exc.message}; retrying in {delay:.1f} s"))
        lane.ready_at = self.clock() + delay

    def _done(self, lane: _Lane, index: int) -> None:
        change = lane.ops[index].change
        elapsed = self.clock() - lane.started[index]
        attempts = lane.tally.get(index, 0)
        self.emit(ApplyEvent(EventKind.DONE, change.address, change.action, elapsed, attempts))
        lane.outcomes.append(Outcome(change, OutcomeStatus.DONE, elapsed, attempts))

    def _fail(self, lane: _Lane, index: int, error: str, attempts_add: int = 0) -> None:
        """The change of operation ``index`` failed: the rest of the lane is skipped."""
        change = lane.ops[index].change
        attempts = lane.tally.get(index, 0) + attempts_add
        elapsed = self.clock() - lane.started.get(index, self.clock())
        self.emit(ApplyEvent(EventKind.FAILED, change.address, change.action, elapsed, attempts, error))
        lane.outcomes.append(Outcome(change, OutcomeStatus.FAILED, elapsed, attempts, error))
        why = f"not attempted: {change.address} failed"
        done = {o.change.address for o in lane.outcomes}
        for rest in [*(lane.ops[i] for i in lane.carried.get(index, ())), *lane.ops[index + 1:]]:
            if rest.change.address in done:
                continue
            done.add(rest.change.address)
            self.emit(ApplyEvent(EventKind.SKIPPED, rest.change.address, rest.change.action, message=why))
            lane.outcomes.append(Outcome(rest.change, OutcomeStatus.SKIPPED, error=why))
        lane.finished = True

    def observed(self, hosts: set[str]) -> tuple[ObservedState, set[str]]:
        """What the agents reported after their last wave, for the hosts they serve; and the
        hosts no such answer covers (to be asked)."""
        brokers: dict[str, ObservedBroker] = {}
        bridges: dict[str, ObservedBridge] = {}
        rest: set[str] = set()
        for host in sorted(hosts):
            try:
                state = self.states.get(id(self.directory.client_for(host)))
            except PlantKGError:
                state = None
            if state is None:
                rest.add(host)
                continue
            for broker in state[0]:
                brokers.setdefault(broker.spec.id, broker)
            for bridge in state[1]:
                bridges.setdefault(bridge.spec.address, bridge)
        return ObservedState(brokers=tuple(sorted(brokers.values(), key=lambda b: b.spec.id)),
                             bridges=tuple(sorted(bridges.values(), key=lambda b: b.spec.address))), rest


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
    settle: float = 15.0,
) -> ApplyResult:
    """Dispatch ``plan`` (made from ``desired``) to the agents, then check it converged.

    ``destroy``: the plan came from :func:`engine.plan.destroy_plan`; the check re-plans that way.
    ``on_event`` is called for every start, finish, retry, failure and skip (one call at a time).
    ``hosts``: the agents to ask again afterwards (default: every host the plan or plant names,
    and the agents file's). ``prune``: the plan was made with ``prune`` (the check re-plans so).
    ``settle``: how long the check asks again while something reported done does not show yet.
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
    runner = _Runner(directory, retries, emit, clock, sleep, rng or random.Random(), parallelism)
    outcomes = runner.run(lanes(operations(plan, desired)))
    order = {c.address: i for i, c in enumerate(plan.changes)}
    outcomes.sort(key=lambda o: order.get(o.change.address, len(order)))
    ask = set(hosts) if hosts is not None else _hosts(plan, desired, directory)
    emit(ApplyEvent(EventKind.VERIFY, "plan", Action.NOOP, message="asking the agents again"))
    known, rest = runner.observed(ask)
    try:
        observed = _merge(known, observe_fn(directory, rest)) if rest else known
    except PlantKGError as exc:  # the changes are made; say what is known, and why no check
        problem = Unexpected("check", f"could not ask the agents again: {exc}")
        return ApplyResult(plan, tuple(outcomes), None, (problem,), clock() - began)
    after = destroy_plan(desired, observed) if destroy else make_plan(desired, observed, prune=prune)
    found = unexpected(plan, outcomes, after)
    deadline, pause = clock() + settle, 0.25
    # What an agent reported done may show late: a Kafka cluster's brokers learn a new topic from
    # the controller's log a moment apart, and the metadata may come from one that has not yet.
    # Ask again (all hosts, fresh) until the differences are gone or ``settle`` seconds passed.
    while _still_pending(outcomes, after) and clock() < deadline:
        sleep(min(pause, max(0.0, deadline - clock())))
        pause = min(pause * 2, 2.0)
        try:
            observed = observe_fn(directory, ask)
        except PlantKGError:
            break  # keep the last check's answer
        after = destroy_plan(desired, observed) if destroy else make_plan(desired, observed, prune=prune)
        found = unexpected(plan, outcomes, after)
    return ApplyResult(plan, tuple(outcomes), after, tuple(found), clock() - began)


def _still_pending(outcomes: Sequence[Outcome], after: Plan) -> bool:
    """Some change an agent reported done is still in the re-made plan."""
    done = {o.change.address for o in outcomes if o.status is OutcomeStatus.DONE}
    return any(c.address in done for c in after.pending)


def _merge(known: ObservedState, asked: ObservedState) -> ObservedState:
    """Two observations of disjoint agents as one (a broker id seen twice: the first kept)."""
    brokers = {b.spec.id: b for b in reversed((*known.brokers, *asked.brokers))}
    bridges = {b.spec.address: b for b in reversed((*known.bridges, *asked.bridges))}
    return ObservedState(brokers=tuple(sorted(brokers.values(), key=lambda b: b.spec.id)),
                         unreachable=asked.unreachable,
                         bridges=tuple(sorted(bridges.values(), key=lambda b: b.spec.address)))


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
