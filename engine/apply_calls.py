"""The agent calls of a plan: which request makes each change, and in which order.

Every pending change becomes one or two agent calls (:func:`operations`): a broker's PUT (or its
DELETE, on the host it runs on; a broker moving host is deleted there first), a topic's PUT or
DELETE on its broker's agent, a bridge's on the agent of its local broker. A topic of a broker the
plan deletes takes no call: the broker's DELETE removes it with the broker's folder (its record and
data), so the change is *carried* by that DELETE and done when it is (before, each rewrote topic
records just before they were moved away: a 100-broker destroy's dispatch took 0.145 s, now 0.098 s,
benchmarks/bench_load at d8eeff6 and d2c44a3). Calls are grouped in
*lanes*, one per broker (:func:`lanes`): a lane runs in plan order (the broker before its topics,
topic deletes before the broker's delete); a lane whose broker takes over an address (host, port)
another broker frees joins that broker's lane after it, so the old broker is gone before the new
one binds. A running Kafka cluster's replaced nodes roll one at a time (their lanes joined, in
node-id order), unless their listener security changes: then they restart all at once (a
whole-cluster restart). Pure functions of the plan and the desired state; :mod:`engine.apply` runs
them.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

from engine.errors import EngineError
from engine.model import Action, BridgeMechanism, Change, DesiredState, Plan
from engine.plan import ALL_TOPIC_SETTINGS, NEW_BROKER_FIELDS, broker_of, restarts_whole_cluster, topic_settings


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
    #: The address of the broker change (a DELETE, in the same lane) whose call also makes this
    #: change; the operation then has no call of its own. None: it is made by its own calls.
    carried_by: str | None = None


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
    return carry_topic_deletes(out)


def carry_topic_deletes(ops: list[Operation]) -> list[Operation]:
    """``ops`` with each topic DELETE of a broker that an operation of ``ops`` deletes (not a
    REPLACE: a broker moving host keeps its topics) turned into an operation without calls,
    carried by that broker's DELETE. Every driver's topics live in the broker's folder, which the
    agent's DELETE moves away whole (a Kafka cluster node's topics are the cluster's and are
    never planned for deletion with the node)."""
    deleted = {broker_of(op.change) for op in ops
               if op.change.action is Action.DELETE and op.change.address.startswith("broker.")}
    return [Operation(op.change, (), carried_by=f"broker.{broker_of(op.change)}")
            if op.change.action is Action.DELETE and op.change.address.startswith("topic.")
            and broker_of(op.change) in deleted else op
            for op in ops]


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
    if spec.mechanism is BridgeMechanism.NGSI:  # the worker writes with the context broker's token
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
        # The cluster's topic changes (planned on its lead) go after the whole roll: a node that
        # restarts after a config change can answer for it with its stale metadata at first
        # (the check after apply once read the old retention from one).
        lane, rolled = merged[dst], set(nodes)
        restarts = [op for op in lane if op.change.address.startswith("broker.") and broker_of(op.change) in rolled]
        merged[dst] = restarts + [op for op in lane if op not in restarts]
    return [lane for lane in merged.values() if lane]


def _rolling(ops: Sequence[Operation]) -> list[list[str]]:
    """Per Kafka cluster, its running nodes that the plan restarts (replace), by node id: their
    lanes are joined so the restarts roll one node at a time — each node's PUT returns once the
    node is back in sync (the driver's health), then the next stops. New nodes start in parallel
    (a new quorum needs its majority up at once), and so do the nodes of a whole-cluster restart
    (:func:`engine.plan.restarts_whole_cluster`: their listener security changes, so a node on the
    new listeners could not join the nodes still on the old ones): their lanes stay apart, so every
    node's PUT goes out in the same wave, each agent stops its node (data kept) and starts it with
    the new configuration, and all are awaited in sync together, under one deadline."""
    clusters: dict[str, list[tuple[int, str]]] = {}
    for op in ops:
        c = op.change
        if c.action is not Action.REPLACE or not c.address.startswith("broker.") or restarts_whole_cluster(c):
            continue
        before, after = (c.before or {}).get("kafka"), (c.after or {}).get("kafka")
        if before and after and before.get("cluster") == after.get("cluster"):
            clusters.setdefault(str(after["cluster"]), []).append((int(after["node_id"]), broker_of(c)))
    return [[b for _, b in sorted(nodes)] for nodes in clusters.values() if len(nodes) > 1]
