"""Plan: compare the desired state with the observed one and list the changes, in order.

``plan(desired, observed)`` is pure (no I/O, no clock): the same two values always give the same
:class:`~engine.model.Plan`. It compares *essences* only — a broker's :class:`BrokerSpec` fields
and, for a topic, the settings that apply to its broker's kind and that the plant sets — so pids,
start times and restart counts never show as drift (kopf's "essence", Terraform's plan).

Change kinds, per address (``broker.<id>``, ``topic.<broker>.<name>``, ``bridge.<local>.<remote>``):

- create: desired, not observed.
- update: changeable in place (a topic's retention or QoS, more partitions, a broker's name), or a
  broker whose essence matches but that is crashed, failed or stopped ("restart").
- replace: a broker's port, host or kind changed; the agent restarts it (a new host or kind means
  a new broker: its topics are created again).
- delete: observed, not desired (a broker's bridges and topics are listed before the broker).
- no-op: nothing to do (kept in ``Plan.changes`` so a plan accounts for every object).

A broker the operator stopped (``plantkg stop``, status stopped-by-operator) is present and
meant to be down: whose essence matches is a no-op, not a restart, and so are the Mosquitto
bridges it carries (its topics are those it had when stopped); only ``plantkg start`` starts it.

A bridge is compared on its essence (both ends' addresses, mechanism, routes), so moving its remote
broker or changing a bridged topic updates the bridge, which the agent of its local broker applies
(a Mosquitto bridge by re-rendering and restarting that broker only, a worker by restarting the
worker). A bridge whose local broker starts anew is created again, like its topics. A worker whose
Kafka opens or closes (``pk:allowAnonymous``, users) is updated, so it logs in there anew: its
remote end's ``closed`` changed.

A node of a Kafka cluster (``BrokerSpec.kafka``, docs/kafka.md) is a broker like the others; a
change of what it renders replaces it (apply rolls a cluster's replaced nodes one at a time), a
change of only its lead flag or broker list is made in place, and a change of a running cluster's
controller quorum is refused. A change of its listener security (``pk:tls`` on or off, closed or
opened: nodes on the old and the new listeners cannot talk to each other) replaces every node as a
*whole-cluster* restart (:func:`restarts_whole_cluster`: its reason says so; apply restarts the
nodes all at once instead of one at a time). The cluster's topics are planned on its lead node
only, and a node that leaves deletes none of them.

Order: brokers, topics, bridges, then deletes (bridges and topics before their broker). Changes a
broker cannot make (fewer Kafka partitions, another replication factor) are :class:`Refusal` s,
and brokers on a host whose agent did not answer are left out and the host listed (what runs there
is unknown, so nothing there can be planned): either makes the plan not applicable.

Ownership (docs/operating.md): agents record the plant that owns each broker, topic and bridge
(``owner``), and ``DesiredState.owner`` names the planning plant. A plant plans only its own
things. What another plant owns, or nobody owns, is listed in ``Plan.foreign`` and never deleted;
with ``prune``, what *nobody* owns (made before ownership existed, or by hand) is deleted — another
plant's things never are. A thing the plant declares that another plant owns is a refusal; one
that nobody owns is a refusal too for a broker (``plantkg import`` takes it over), while a topic
or bridge on the plant's own broker is adopted (an update that records the owner). A plant that
declares no owner (``owner`` None) owns exactly what nobody owns, as before ownership existed.
"""

from __future__ import annotations

import enum
import json
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, fields, replace
from typing import Any

from engine.derived.access import open_broker_warnings
from engine.model import (
    Action,
    BridgeSpec,
    BridgeStatus,
    BrokerSpec,
    BrokerStatus,
    BrokerUser,
    Change,
    DesiredState,
    Foreign,
    ObservedBridge,
    ObservedBroker,
    ObservedState,
    ObservedTopic,
    Plan,
    Refusal,
    TopicSpec,
    to_dict,
)

#: Broker fields whose change needs a new broker process (the agent restarts it): Terraform's
#: "forces replacement". Every other BrokerSpec field is changed in place.
REPLACE_FIELDS: tuple[str, ...] = ("kind", "host", "port", "persist_every", "allow_anonymous", "mqtt_port",
                                   "users", "tls", "certificate_port", "kafka", "closed_kafkas", "tls_kafkas")
#: Fields of a cluster node's ``kafka`` that are not rendered into its config: a change of only
#: these (the cluster gained a broker, the lead moved) is made in place.
KAFKA_IN_PLACE: tuple[str, ...] = ("lead", "bootstrap")
#: Replace fields after which the broker starts empty (its topics are created again).
NEW_BROKER_FIELDS: tuple[str, ...] = ("kind", "host")

#: Topic settings that mean something to each broker kind; a setting of another kind is ignored.
#: A kind missing here compares every setting the plant gives.
TOPIC_SETTINGS: Mapping[str, tuple[str, ...]] = {
    "kafka": ("partitions", "replication_factor", "retention_ms", "min_insync_replicas"),
    "mosquitto": ("qos", "retain"),
    "ngsi-v2": ("entity_id", "entity_type"),
}
ALL_TOPIC_SETTINGS: tuple[str, ...] = tuple(
    f.name for f in fields(ObservedTopic) if f.name not in ("name", "owner")
)

#: Statuses after which a broker whose essence matches is started again.
RESTART_STATUSES: frozenset[BrokerStatus] = frozenset(
    {BrokerStatus.CRASHED, BrokerStatus.FAILED, BrokerStatus.STOPPED}
)

#: Bridge statuses after which a bridge whose essence matches is started again.
BRIDGE_RESTART_STATUSES: frozenset[BridgeStatus] = frozenset(
    {BridgeStatus.CRASHED, BridgeStatus.FAILED, BridgeStatus.STOPPED}
)

_ORDER = {"broker": 0, "topic": 1, "bridge": 2}
_DELETE_ORDER = {"bridge": 0, "topic": 1, "broker": 2}


# ------------------------------------------------------------------------------------- essences

def broker_essence(spec: BrokerSpec) -> dict[str, Any]:
    """The fields of a broker the plan compares (all of BrokerSpec), as JSON-able values; no
    ``users`` key for a broker without users, no ``tls`` key for a plain one, no ``kafka``
    key for a broker that is not a cluster's node, no ``closed_kafkas`` or ``tls_kafkas`` key for
    a broker told none and no ``certificate_port`` key for a broker without a certificate listener, so plans of
    other brokers read as before. A user shows its secret reference, never a secret (the plan has
    none), and ``"certificate": true`` when it may log in with a client certificate (a
    certificate user without a password shows no ``secret_ref``)."""
    out = {f.name: getattr(spec, f.name) for f in fields(spec)
           if f.name not in ("users", "tls", "certificate_port", "kafka", "closed_kafkas", "tls_kafkas")}
    if spec.users:
        out["users"] = [user_essence(u) for u in spec.users]
    if spec.tls:
        out["tls"] = True
    if spec.certificate_port is not None:
        out["certificate_port"] = spec.certificate_port
    if spec.kafka is not None:  # a node of a cluster
        out["kafka"] = to_dict(spec.kafka)
    if spec.closed_kafkas:  # a context broker whose kafka:// notifications log in there
        out["closed_kafkas"] = list(spec.closed_kafkas)
    if spec.tls_kafkas:  # ... and reach over TLS
        out["tls_kafkas"] = list(spec.tls_kafkas)
    return out


def user_essence(user: BrokerUser) -> dict[str, Any]:
    """A broker user as a plan shows it: name, secret reference (absent for a certificate user
    without a password), rights, and ``certificate`` only when true."""
    out = {"name": user.name, **({} if user.secret_ref is None else {"secret_ref": user.secret_ref}),
           "write": list(user.write), "read": list(user.read)}
    if user.certificate:
        out["certificate"] = True
    return out


def bridge_essence(spec: BridgeSpec) -> dict[str, Any]:
    """The fields of a bridge the plan compares: all but ``asserted`` (which is for people), and
    no unset optional route field (a route's entity id and type belong to NGSI bridges only)."""
    data = to_dict(spec)
    data.pop("asserted")
    for end in ("local", "remote"):  # a plain end, not a Kafka cluster, reads as before
        for flag in ("tls", "closed"):
            if not data[end][flag]:
                del data[end][flag]
        if not data[end]["bootstrap"]:
            data[end].pop("bootstrap")
    data["routes"] = [{k: v for k, v in route.items() if v is not None} for route in data["routes"]]
    return data


def topic_settings(kind: str) -> tuple[str, ...]:
    """The topic settings that apply to a broker of ``kind``."""
    return TOPIC_SETTINGS.get(kind, ALL_TOPIC_SETTINGS)


def topic_essence(topic: TopicSpec | ObservedTopic, broker_id: str, settings: Iterable[str]) -> dict[str, Any]:
    """A topic's identity plus ``settings`` (a desired topic: only the ones the plant sets)."""
    out: dict[str, Any] = {"broker_id": broker_id, "name": topic.name}
    for name in settings:
        value = getattr(topic, name)
        if value is not None or isinstance(topic, ObservedTopic):
            out[name] = value
    return out


# ------------------------------------------------------------------------------------- planning

class Ownership(str, enum.Enum):
    """Whose a thing an agent runs is, seen from the planning plant."""

    MINE = "mine"        # owned by the planning plant
    NOBODY = "nobody"    # owned by no plant (made before ownership existed, or by hand)
    OTHER = "other"      # owned by another plant


def ownership(owner: str | None, mine: str | None) -> Ownership:
    """``owner`` (what the agent recorded) seen from the plant that owns ``mine``."""
    if owner == mine:
        return Ownership.MINE
    return Ownership.NOBODY if owner is None else Ownership.OTHER


class PlanMemo:
    """What :func:`plan` concluded per desired broker, keyed by everything that conclusion reads
    (the broker's spec and topics, what its agent reported, the owner, ``prune``), so a re-plan
    after a small edit recomputes only the brokers whose inputs changed (engine.incremental.replan). The
    inputs are compared for equality; kept specs are the same objects, so that is quick."""

    def __init__(self) -> None:
        self.brokers: dict[str, tuple[tuple[object, ...], tuple[object, ...]]] = {}
        self.bridges: dict[str, tuple[tuple[object, ...], tuple[object, ...]]] = {}


def plan(desired: DesiredState, observed: ObservedState, *, prune: bool = False,
         memo: PlanMemo | None = None) -> Plan:
    """The ordered changes that turn ``observed`` into ``desired`` (pure).

    Only the things ``desired.owner`` owns are changed; ``prune`` also deletes what nobody owns.
    ``memo`` (kept by the caller between plans) reuses each broker's conclusion while its inputs
    are unchanged; the plan is the same with or without it."""
    owner = desired.owner
    unreachable = frozenset(observed.unreachable)
    changes: list[Change] = []
    refusals: list[Refusal] = []
    deletes: list[Change] = []
    foreign: list[Foreign] = []
    fresh_brokers: set[str] = set()
    claimed: set[str] = set()
    seen: dict[str, tuple[tuple[object, ...], tuple[object, ...]]] = {}
    sort_keys: list[tuple[int, str]] = []  # with a memo: the sort key of each change, in order
    for spec in desired.brokers:
        if spec.host in unreachable:
            continue  # its state is unknown: no change is planned, the host is listed
        have = observed.broker(spec.id)
        wanted_topics = desired.topics_of(spec.id)
        key = (spec, wanted_topics, have, owner, prune)
        cached = memo.brokers.get(spec.id) if memo is not None else None
        if cached is not None and cached[0] == key:
            done = cached[1]
        else:
            done = _plan_broker(spec, wanted_topics, have, owner, prune)
            if memo is not None:
                claim, broker_change, _, topics = done
                if claim is None:
                    done = (*done, [_sort_key(c) for c in (broker_change, *topics.changes)])  # type: ignore[union-attr]
        seen[spec.id] = (key, done)
        claim, broker_change, fresh, topics = done[:4]
        if claim is not None:
            refusals.append(claim)  # type: ignore[arg-type]
            claimed.add(spec.id)
            continue
        quorum = _quorum_refusal(spec, have)
        if quorum is not None:
            refusals.append(quorum)
            continue
        if memo is not None:
            sort_keys.extend(done[4])  # type: ignore[arg-type]
        changes.append(broker_change)  # type: ignore[arg-type]
        if fresh:
            fresh_brokers.add(spec.id)
        changes.extend(topics.changes)  # type: ignore[union-attr]
        refusals.extend(topics.refusals)  # type: ignore[union-attr]
        deletes.extend(topics.deletes)  # type: ignore[union-attr]
        foreign.extend(topics.foreign)  # type: ignore[union-attr]
    if memo is not None:
        memo.brokers = seen
    wanted = {b.id for b in desired.brokers}
    for have in observed.brokers:
        if have.spec.id in wanted:
            continue
        whose = ownership(have.owner, owner)
        if whose is Ownership.MINE:
            deletes.extend(_broker_delete(have))
        elif whose is Ownership.NOBODY and prune:
            deletes.extend(_broker_delete(have, _PRUNED))
        else:
            foreign.append(_foreign(have.spec.address, have.owner))
    hosts = {b.id: b.host for b in desired.brokers}
    held = {b.spec.id for b in observed.brokers if b.status is BrokerStatus.STOPPED_BY_OPERATOR}
    bridges_seen: dict[str, tuple[tuple[object, ...], tuple[object, ...]]] = {}
    for bridge in desired.bridges:
        if hosts.get(bridge.local.id) in unreachable or bridge.local.id in claimed:
            continue
        have = None if bridge.local.id in fresh_brokers else observed.bridge(bridge.address)
        key = (bridge, have, bridge.local.id in held, owner)
        cached = memo.bridges.get(bridge.address) if memo is not None else None
        done = (cached[1] if cached is not None and cached[0] == key
                else _plan_bridge(bridge, have, key[2], owner))
        bridges_seen[bridge.address] = (key, done)
        refusal, change = done
        if refusal is not None:
            refusals.append(refusal)  # type: ignore[arg-type]
        else:
            changes.append(change)  # type: ignore[arg-type]
            if memo is not None:
                sort_keys.append(_sort_key(change))  # type: ignore[arg-type]
    if memo is not None:
        memo.bridges = bridges_seen
    wanted_bridges = {b.address for b in desired.bridges}
    for seen in observed.bridges:
        if seen.spec.address in wanted_bridges:
            continue
        whose = ownership(seen.owner, owner)
        if whose is Ownership.MINE:
            deletes.append(_bridge_delete(seen.spec))
        elif whose is Ownership.NOBODY and prune:
            deletes.append(_bridge_delete(seen.spec, _PRUNED))
        else:
            foreign.append(_foreign(seen.spec.address, seen.owner))
    if memo is None:
        changes.sort(key=_sort_key)
    else:  # the memo's keys, sorted by index: no Python call per change
        changes = [changes[i] for i in sorted(range(len(changes)), key=sort_keys.__getitem__)]
    deletes.sort(key=_delete_key)
    return Plan(
        changes=tuple(changes) + tuple(deletes),
        refusals=tuple(sorted(refusals, key=lambda r: r.address)),
        unreachable=tuple(sorted(unreachable)),
        foreign=tuple(sorted(foreign, key=lambda f: f.address)),
        warnings=open_broker_warnings(desired.brokers),
    )


def _plan_broker(spec: BrokerSpec, wanted_topics: tuple[TopicSpec, ...], have: ObservedBroker | None,
                 owner: str | None, prune: bool) -> tuple[object, ...]:
    """One desired broker's part of the plan: (refusal when another plant or nobody holds it,
    its change, whether it starts empty, its topics' changes)."""
    if have is not None and ownership(have.owner, owner) is not Ownership.MINE:
        return (_claimed_refusal(spec.address, have.owner, importable=True), None, False, None)
    broker_change = _broker_change(spec, have)
    fresh = broker_change.action is Action.CREATE or (
        broker_change.action is Action.REPLACE and _starts_empty(broker_change)
    )
    topics = _topic_changes(spec, wanted_topics, have, fresh, owner, prune)
    return (None, broker_change, fresh, topics)


def _plan_bridge(bridge: BridgeSpec, have: ObservedBridge | None, held: bool,
                 owner: str | None) -> tuple[Refusal | None, Change | None]:
    """One desired bridge's part of the plan: a refusal (another plant's) or its change."""
    whose = Ownership.MINE if have is None else ownership(have.owner, owner)
    if whose is Ownership.OTHER:
        return _claimed_refusal(bridge.address, have.owner if have else None, importable=False), None
    change = _bridge_change(bridge, have, held)
    return None, (_adopted(change, owner) if whose is Ownership.NOBODY else change)


def destroy_plan(desired: DesiredState, observed: ObservedState) -> Plan:
    """Delete what the plant deployed, and nothing else.

    With an owner: every broker and bridge the plant owns (named in the plant or not any more),
    with their topics. Without (``desired.owner`` None): the observed brokers that ``desired``
    names and that nobody owns, with their topics and bridges. Everything else is foreign.
    """
    owner = desired.owner
    if owner is None:
        ours = {b.id for b in desired.brokers}
        mine_broker = lambda b: b.spec.id in ours and b.owner is None  # noqa: E731
        mine_bridge = lambda b: b.spec.local.id in ours and b.owner is None  # noqa: E731
    else:
        mine_broker = lambda b: b.owner == owner  # noqa: E731
        mine_bridge = lambda b: b.owner == owner  # noqa: E731
    mine = ObservedState(
        brokers=tuple(b for b in observed.brokers if mine_broker(b)),
        unreachable=observed.unreachable,
        bridges=tuple(b for b in observed.bridges if mine_bridge(b)),
    )
    result = plan(DesiredState(owner=owner), mine)
    foreign = [_foreign(b.spec.address, b.owner) for b in observed.brokers if not mine_broker(b)]
    foreign += [_foreign(b.spec.address, b.owner) for b in observed.bridges if not mine_bridge(b)]
    return Plan(tuple(replace(c, reason="destroy: the plant owns it" if owner is not None
                              else "destroy: the plant names it") for c in result.changes),
                result.refusals, result.unreachable,
                tuple(sorted(foreign, key=lambda f: f.address)))


_PRUNED = "prune: nobody owns it (made before ownership, or by hand)"


def _foreign(address: str, owner: str | None) -> Foreign:
    if owner is None:
        return Foreign(address, None, "nobody owns it: left alone (--prune deletes it, "
                                      "`plantkg import` takes a broker over)")
    return Foreign(address, owner, f"owned by plant {owner}: left alone")


def _claimed_refusal(address: str, owner: str | None, *, importable: bool) -> Refusal:
    """The plant declares something another plant (or nobody) owns on its agent."""
    if owner is None:
        return Refusal(address, f"{address} already runs and nobody owns it (made before ownership, "
                                f"or by hand): `plantkg import {address}` takes it over for this "
                                "plant, or give it another pk:id")
    how = "" if importable else " on its broker"
    return Refusal(address, f"{address} already runs{how}, owned by plant {owner}: plantkg never "
                            "changes another plant's things; give it another pk:id, or destroy it "
                            "from its own plant first")


def _adopted(change: Change, owner: str | None) -> Change:
    """``change`` of a thing nobody owns on the plant's own broker, made an update that records
    ``owner`` as its owner (the agent stores it with the PUT)."""
    before = {**(change.before or {}), "owner": None}
    after = {**(change.after or {}), "owner": owner}
    why = "adopt: nobody owns it; the plant declares it on its own broker"
    if change.action is not Action.NOOP and change.reason:
        why += f"; {change.reason}"
    action = Action.UPDATE if change.action is Action.NOOP else change.action
    return Change(change.address, action, before, after, why)


def _broker_change(spec: BrokerSpec, have: ObservedBroker | None) -> Change:
    after = broker_essence(spec)
    if have is None:
        return Change(spec.address, Action.CREATE, None, after, "not running on its host")
    before = broker_essence(have.spec)
    forced = [f for f in REPLACE_FIELDS if _rendered(f, before.get(f)) != _rendered(f, after.get(f))]
    if forced:
        what = ", ".join(_forced(f, before.get(f), after.get(f)) for f in forced)
        if before["host"] != after["host"]:
            how = "the broker moves: stopped on the old host, started anew on the new one"
        elif before["kind"] != after["kind"]:
            how = "the broker is stopped and started anew as the new kind"
        elif restarts_whole_cluster(Change(spec.address, Action.REPLACE, before, after)):
            how = ("whole cluster: listener security changes; every node of the cluster is stopped and "
                   "started again at once, its data kept, then all are awaited in sync")
        else:
            how = "the agent restarts the broker"
        return Change(spec.address, Action.REPLACE, before, after, f"{what} forces replacement ({how})")
    if before != after:
        changed = ", ".join(f for f in after if before.get(f) != after[f])
        return Change(spec.address, Action.UPDATE, before, after, f"{changed} changed in place")
    if have.status is BrokerStatus.STOPPED_BY_OPERATOR:
        return Change(spec.address, Action.NOOP, before, after,
                      f"stopped by the operator: `plantkg start {spec.id}` starts it")
    if have.tls_renew is not None and have.status is BrokerStatus.RUNNING:
        return Change(spec.address, Action.UPDATE, {**before, "tls_certificate": have.tls_renew},
                      {**after, "tls_certificate": "renewed"},
                      f"its TLS certificate is due ({have.tls_renew}): the agent issues a new one "
                      "and restarts the broker")
    if have.status in RESTART_STATUSES:
        detail = f": {have.last_error}" if have.last_error else ""
        return Change(spec.address, Action.UPDATE,
                      {**before, "status": have.status.value},
                      {**after, "status": BrokerStatus.RUNNING.value},
                      f"restart: the broker is {have.status.value}{detail}")
    return Change(spec.address, Action.NOOP, before, after)


def _forced(field: str, old: Any, new: Any) -> str:
    """A forced field's change for the reason; a cluster node's ``kafka`` by the keys that changed."""
    if field == "kafka" and isinstance(old, Mapping) and isinstance(new, Mapping):
        keys = [k for k in new if k not in KAFKA_IN_PLACE and old.get(k) != new[k]]
        return ", ".join(f"kafka.{k} {_show(old.get(k))} → {_show(new[k])}" for k in keys)
    return f"{field} {_show(old)} → {_show(new)}"


def _rendered(field: str, value: Any) -> Any:
    """What of a broker field its process runs with: a cluster node's ``kafka`` without the
    fields made in place (:data:`KAFKA_IN_PLACE`)."""
    if field == "kafka" and isinstance(value, Mapping):
        return {k: v for k, v in value.items() if k not in KAFKA_IN_PLACE}
    return value


def _quorum_refusal(spec: BrokerSpec, have: ObservedBroker | None) -> Refusal | None:
    """A running cluster node whose controller quorum would change: KRaft's static quorum
    (controller.quorum.voters) cannot change under a running cluster."""
    if have is None or have.spec.kafka is None or spec.kafka is None:
        return None
    old, new = have.spec.kafka.voters, spec.kafka.voters
    if old == new:
        return None
    show = lambda voters: ", ".join(f"{v.node_id}@{v.host}:{v.port}" for v in voters)  # noqa: E731
    return Refusal(spec.address, f"the controller quorum of cluster {spec.kafka.cluster!r} would change "
                                 f"({show(old)} → {show(new)}): a running KRaft cluster keeps its "
                                 "controllers; add or remove nodes with the 'broker' role only, or "
                                 "keep the controllers' pk:ip, pk:port and pk:controllerPort")


def listener_security(essence: Mapping[str, Any]) -> tuple[bool, bool]:
    """What a Kafka broker's listeners speak, all of them (clients, and in a cluster replication and
    the controllers), from its essence (:func:`broker_essence`): (TLS, closed: SASL; as
    engine.security.kafka_client.is_closed says). A cluster's nodes speak it all together
    (engine.derived.access)."""
    return bool(essence.get("tls")), essence.get("allow_anonymous") is False or bool(essence.get("users"))


def restarts_whole_cluster(change: Change) -> bool:
    """A cluster node's replacement that changes its listener security (``pk:tls`` on or off, the
    cluster closed or opened): a node on the new listeners cannot reach the nodes still on the old
    ones (KRaft quorum, replication), so the nodes cannot roll one at a time; apply restarts them
    all at once instead (engine.apply_calls)."""
    if change.action is not Action.REPLACE or not change.before or not change.after:
        return False
    before, after = change.before.get("kafka"), change.after.get("kafka")
    return (bool(before) and bool(after) and before.get("cluster") == after.get("cluster")
            and listener_security(change.before) != listener_security(change.after))


def _bridge_change(spec: BridgeSpec, have: ObservedBridge | None, held: bool = False) -> Change:
    """``held``: its local broker is stopped by the operator (a stopped bridge is meant)."""
    after = bridge_essence(spec)
    if have is None:
        return Change(spec.address, Action.CREATE, None, after, "not running on its broker's agent")
    before = bridge_essence(have.spec)
    if before != after:
        changed = ", ".join(k for k in after if before.get(k) != after[k])
        how = ("its broker restarts with the new bridge" if spec.mechanism.value == "mosquitto"
               else "its worker restarts")
        return Change(spec.address, Action.UPDATE, before, after, f"{changed} changed ({how})")
    if have.status in BRIDGE_RESTART_STATUSES and not held:
        detail = f": {have.last_error}" if have.last_error else ""
        return Change(spec.address, Action.UPDATE, {**before, "status": have.status.value},
                      {**after, "status": BridgeStatus.RUNNING.value},
                      f"restart: the bridge is {have.status.value}{detail}")
    return Change(spec.address, Action.NOOP, before, after)


def _bridge_delete(spec: BridgeSpec, reason: str = "not in the plant") -> Change:
    return Change(spec.address, Action.DELETE, bridge_essence(spec), None, reason)


def _starts_empty(change: Change) -> bool:
    assert change.before is not None and change.after is not None
    return any(change.before[f] != change.after[f] for f in NEW_BROKER_FIELDS)


@dataclass(frozen=True)
class _TopicPlan:
    changes: list[Change]
    refusals: list[Refusal]
    deletes: list[Change]
    foreign: list[Foreign]


def _topic_changes(
    spec: BrokerSpec, topics: Iterable[TopicSpec], have: ObservedBroker | None, fresh: bool,
    owner: str | None = None, prune: bool = False,
) -> _TopicPlan:
    """Changes for the topics of one desired broker; observed topics not desired are deleted if
    the plant owns them (or nobody does and ``prune``), else listed as foreign."""
    settings = topic_settings(spec.kind)
    present = {} if (have is None or fresh) else {t.name: t for t in have.topics}
    out = _TopicPlan([], [], [], [])
    wanted: set[str] = set()
    for topic in topics:
        wanted.add(topic.name)
        after = topic_essence(topic, spec.id, settings)
        old = present.get(topic.name)
        if old is None:
            why = "its broker starts anew" if fresh and have is not None else "not on the broker"
            out.changes.append(Change(topic.address, Action.CREATE, None, after, why))
            continue
        whose = ownership(old.owner, owner)
        if whose is Ownership.OTHER:
            out.refusals.append(_claimed_refusal(topic.address, old.owner, importable=False))
            continue
        before = topic_essence(old, spec.id, [k for k in after if k not in ("broker_id", "name")])
        if before == after:
            change = Change(topic.address, Action.NOOP, before, after)
        else:
            refused = _refusal(topic.address, before, after)
            if refused is not None:
                out.refusals.append(refused)
                continue
            changed = ", ".join(f"{k} {_show(before[k])} → {_show(after[k])}"
                                for k in after if before[k] != after[k])
            change = Change(topic.address, Action.UPDATE, before, after, f"{changed} (in place)")
        out.changes.append(_adopted(change, owner) if whose is Ownership.NOBODY else change)
    if have is None:
        return out
    for name, t in sorted(present.items()):
        if name in wanted:
            continue
        whose = ownership(t.owner, owner)
        if whose is Ownership.MINE:
            out.deletes.append(_topic_delete(spec.id, t, topic_settings(have.spec.kind)))
        elif whose is Ownership.NOBODY and prune:
            out.deletes.append(_topic_delete(spec.id, t, topic_settings(have.spec.kind), _PRUNED))
        else:
            out.foreign.append(_foreign(f"topic.{spec.id}.{name}", t.owner))
    return out


def _show(value: Any) -> str:
    """A value in a reason, as JSON writes it (strings quoted, None as null)."""
    return json.dumps(value)


def _refusal(address: str, before: Mapping[str, Any], after: Mapping[str, Any]) -> Refusal | None:
    """A change no broker can make in place, or None."""
    old, new = before.get("partitions"), after.get("partitions")
    if old is not None and new is not None and new < old:
        return Refusal(address, f"partitions {old} → {new}: Kafka cannot remove partitions; keep "
                                f"{old} or more, or give the topic another name")
    old, new = before.get("replication_factor"), after.get("replication_factor")
    if old is not None and new is not None and new != old:
        return Refusal(address, f"replication factor {old} → {new}: cannot be changed in place; "
                                f"keep {old}, or give the topic another name")
    return None


def _topic_delete(broker_id: str, topic: ObservedTopic, settings: Iterable[str],
                  reason: str = "not in the plant") -> Change:
    before = topic_essence(topic, broker_id, settings)
    return Change(f"topic.{broker_id}.{topic.name}", Action.DELETE, before, None, reason)


def _broker_delete(have: ObservedBroker, reason: str = "not in the plant") -> list[Change]:
    settings = topic_settings(have.spec.kind)
    # A cluster node's topics are the cluster's: they stay when one node goes.
    topics = () if have.spec.kafka is not None else have.topics
    out = [_topic_delete(have.spec.id, t, settings, reason)
           for t in sorted(topics, key=lambda t: t.name)]
    out.append(Change(have.spec.address, Action.DELETE, broker_essence(have.spec), None, reason))
    return out


def _sort_key(change: Change) -> tuple[int, str]:
    return _ORDER[change.address.split(".", 1)[0]], change.address


def _delete_key(change: Change) -> tuple[str, int, str]:
    """Deletes grouped by broker, a broker's bridges, then topics, before the broker itself."""
    kind = change.address.split(".", 1)[0]
    return broker_of(change), _DELETE_ORDER[kind], change.address


def broker_of(change: Change) -> str:
    """The broker id a change belongs to (a bridge belongs to its local, carrying broker)."""
    kind, rest = change.address.split(".", 1)
    if kind == "broker":
        return rest
    data = change.before or change.after or {}
    if kind == "topic":
        return str(data["broker_id"])
    return str(data["local"]["id"])
