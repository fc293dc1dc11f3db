"""The engine's calls to an agent as data, for a batch (``AgentClient.batch``, ``POST /v1/batch``).

:class:`AgentCall` names one of the client's verbs with its arguments (``put_broker(spec)``,
``delete_topic(broker_id, name)`` ...); a batch sends lanes of them at once and answers a
:class:`CallResult` per call: done, failed with the error the single call would have raised (a
:class:`~engine.errors.DispatchError`: temporary or permanent, with the agent's message and
hint), or skipped because an earlier call of its lane failed. Plain data, no HTTP: apply builds
them, the client and the test double of the agents run them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from engine.errors import DispatchError
from engine.model import ObservedBridge, ObservedBroker

#: The verbs a batch carries (AgentClient methods that change something).
VERBS = ("put_broker", "delete_broker", "put_topic", "delete_topic", "put_bridge", "delete_bridge")


@dataclass(frozen=True)
class AgentCall:
    """``verb(*args, owner=owner, remote_token=remote_token)`` on an AgentClient; ``owner`` and
    ``remote_token`` are passed only when set (a client from before ownership takes neither)."""

    verb: str
    args: tuple[Any, ...]
    owner: str | None = None
    remote_token: str | None = field(default=None, repr=False)  # never in a log

    def __post_init__(self) -> None:
        if self.verb not in VERBS:
            raise ValueError(f"{self.verb!r} is not a batch verb ({', '.join(VERBS)})")

    def kwargs(self) -> dict[str, Any]:
        extra: dict[str, Any] = {} if self.owner is None else {"owner": self.owner}
        if self.remote_token is not None:
            extra["remote_token"] = self.remote_token
        return extra


@dataclass(frozen=True)
class CallResult:
    """One call's result: ``done``; else ``error`` (it failed) or neither (it was skipped)."""

    done: bool
    error: DispatchError | None = None

    @property
    def skipped(self) -> bool:
        return not self.done and self.error is None


DONE = CallResult(True)
SKIPPED = CallResult(False)


@dataclass(frozen=True)
class BatchAnswer:
    """A result per call, in the lanes' shape; with ``observe``, what the agent runs afterwards
    (None: not asked, or not known for the moment after every lane)."""

    lanes: tuple[tuple[CallResult, ...], ...]
    brokers: tuple[ObservedBroker, ...] | None = None
    bridges: tuple[ObservedBridge, ...] | None = None

    @property
    def observed(self) -> bool:
        return self.brokers is not None and self.bridges is not None


def run_calls(client: Any, lanes: list[list[AgentCall]]) -> BatchAnswer:
    """A batch made of single calls, one after another (for a client that talks to something
    without a batch of its own: the test double of the agents)."""
    out = []
    for lane in lanes:
        results: list[CallResult] = []
        for call in lane:
            if results and not results[-1].done:
                results.append(SKIPPED)
                continue
            try:
                getattr(client, call.verb)(*call.args, **call.kwargs())
                results.append(DONE)
            except DispatchError as exc:
                results.append(CallResult(False, exc))
        out.append(tuple(results))
    return BatchAnswer(tuple(out))
