"""``POST /v1/batch``: many changes in one request, in lanes, each with its own result.

An engine applying a plan used to send one request per change (a broker, then each of its
topics, then its bridges): 2-3 round trips per broker, and a 100-broker plant spent most of its
apply on them. A batch carries them all::

    {"lanes": [[{"op": "put_broker", "spec": {...}, "owner": "cell"},
                {"op": "put_topic", "spec": {...}, "owner": "cell"}],
               [{"op": "delete_topic", "broker_id": "old", "name": "t"},
                {"op": "delete_broker", "broker_id": "old"}]],
     "observe": true}

- The items of a lane run in order; the lanes run at the same time. Each lane's first
  ``put_broker`` or ``delete_broker`` runs in one step with those of the other lanes (what comes
  before it in its lane first, what comes after it afterwards): the agent spawns every broker,
  then awaits them all in one polling loop (``BrokerManager.put_many``), and sends SIGTERM to
  every broker before it waits for any (``BrokerManager.delete_many``). So N brokers take about
  as long to start or stop as one, without N threads polling against each other.
- Each item is exactly the single request it stands for (same checks, same owner rule, same
  error and status: :mod:`engine.agent.changes`). A failed item leaves the rest of its lane not
  attempted (``skipped``); other lanes go on. So a broker whose start fails keeps its topics from
  being created on nothing, and no other broker notices.
- The answer has one result per item, in the request's shape: ``{"outcome": "done", "status":
  200, "answer": {...}}``, ``{"outcome": "failed", "status": 409, "error": {...}}`` or
  ``{"outcome": "skipped"}``; with ``"observe": true`` also ``brokers`` and ``bridges`` as the
  list routes answer them after every lane finished (the engine's check after apply needs no
  further request).
- A request that is malformed anywhere (not JSON, an unknown op, a spec that does not parse) is
  refused whole with 400 naming the field (``lanes[1][0].spec.port``): nothing is done.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from engine.agent.changes import REMOTE_TOKEN, Changes, check_remote_token, error_status
from engine.agent.fanout import each
from engine.agent.owners import OWNER_FIELD, check_owner
from engine.agent.wire import BROKER_ID, WireError, bridge_spec_from_json, broker_spec_from_json, topic_spec_from_json
from engine.model import to_dict

#: At most this many lanes (each runs on a thread of its own) and items in one batch.
MAX_LANES = 512
MAX_ITEMS = 4096

#: op -> the fields an item of it has besides ``op`` and ``owner`` (required, then optional).
OPS: dict[str, tuple[tuple[str, ...], tuple[str, ...]]] = {
    "put_broker": (("spec",), ()),
    "delete_broker": (("broker_id",), ()),
    "put_topic": (("spec",), ()),
    "delete_topic": (("broker_id", "name"), ()),
    "put_bridge": (("spec",), (REMOTE_TOKEN,)),
    "delete_bridge": (("broker_id", "remote_id"), ()),
}


@dataclass(frozen=True)
class Item:
    """One parsed change: ``run(changes)`` makes it and returns its answer (or None)."""

    op: str
    what: str
    run: Callable[[Changes], Any]
    #: put_broker: (spec, owner); delete_broker: (broker id, owner); run with its batch's others.
    broker: tuple[Any, str | None] | None = None

    @property
    def broker_id(self) -> str | None:
        if self.broker is None:
            return None
        key = self.broker[0]
        return key if isinstance(key, str) else key.id


def parse_batch(body: Any) -> tuple[list[list[Item]], bool]:
    """The lanes of a batch body and its ``observe`` flag; WireError naming the field at fault."""
    if not isinstance(body, dict):
        raise WireError("body", "expected a JSON object with 'lanes'")
    unknown = sorted(set(body) - {"lanes", "observe"})
    if unknown:
        raise WireError(unknown[0], "unknown field (a batch has 'lanes' and 'observe')")
    observe = body.get("observe", False)
    if not isinstance(observe, bool):
        raise WireError("observe", "expected true or false")
    lanes = body.get("lanes")
    if not isinstance(lanes, list):
        raise WireError("lanes", "missing, or not an array of lanes")
    if len(lanes) > MAX_LANES:
        raise WireError("lanes", f"{len(lanes)} lanes; a batch has at most {MAX_LANES}")
    parsed: list[list[Item]] = []
    count = 0
    for i, lane in enumerate(lanes):
        if not isinstance(lane, list) or not lane:
            raise WireError(f"lanes[{i}]", "expected a non-empty array of items")
        count += len(lane)
        if count > MAX_ITEMS:
            raise WireError("lanes", f"more than {MAX_ITEMS} items in one batch")
        parsed.append([parse_item(item, f"lanes[{i}][{j}]") for j, item in enumerate(lane)])
    return parsed, observe


def parse_item(data: Any, where: str) -> Item:
    """One item of a lane, checked as its single request would be."""
    if not isinstance(data, dict):
        raise WireError(where, "expected an object with 'op'")
    op = data.get("op")
    if not isinstance(op, str) or op not in OPS:
        raise WireError(f"{where}.op", f"expected one of {', '.join(OPS)}")
    required, optional = OPS[op]
    unknown = sorted(set(data) - {"op", OWNER_FIELD, *required, *optional})
    if unknown:
        raise WireError(f"{where}.{unknown[0]}", f"unknown field of a {op} item")
    for name in required:
        if name not in data:
            raise WireError(f"{where}.{name}", "missing")
    owner = check_owner(data.get(OWNER_FIELD), f"{where}.{OWNER_FIELD}")
    if op == "put_broker":
        broker = broker_spec_from_json(data["spec"], f"{where}.spec")
        return Item(op, f"PUT broker {broker.id}", lambda c: c.put_broker(broker, owner), (broker, owner))
    if op == "put_topic":
        topic = topic_spec_from_json(data["spec"], f"{where}.spec")
        _check_id(topic.broker_id, f"{where}.spec.broker_id")
        return Item(op, f"PUT topic {topic.broker_id}/{topic.name}", lambda c: c.put_topic(topic, owner))
    if op == "put_bridge":
        bridge = bridge_spec_from_json(data["spec"], f"{where}.spec")
        token = check_remote_token(data.get(REMOTE_TOKEN), bridge.mechanism, f"{where}.{REMOTE_TOKEN}")
        _check_id(bridge.local.id, f"{where}.spec.local.id")
        _check_id(bridge.remote.id, f"{where}.spec.remote.id")
        return Item(op, f"PUT bridge {bridge.address}", lambda c: c.put_bridge(bridge, owner, token))
    broker_id = _check_id(data["broker_id"], f"{where}.broker_id")
    if op == "delete_broker":
        return Item(op, f"DELETE broker {broker_id}", lambda c: c.delete_broker(broker_id, owner),
                    (broker_id, owner))
    if op == "delete_topic":
        name = data["name"]
        if not isinstance(name, str) or not name:
            raise WireError(f"{where}.name", "expected a non-empty topic name")
        return Item(op, f"DELETE topic {broker_id}/{name}", lambda c: c.delete_topic(broker_id, name, owner))
    remote_id = _check_id(data["remote_id"], f"{where}.remote_id")
    return Item(op, f"DELETE bridge {broker_id}->{remote_id}",
                lambda c: c.delete_bridge(broker_id, remote_id, owner))


def _check_id(value: Any, where: str) -> str:
    if not isinstance(value, str) or not BROKER_ID.fullmatch(value):
        raise WireError(where, "a broker id is 1 to 128 characters of A-Z a-z 0-9 _ . - starting "
                               "with a letter, a digit or _")
    return value


def run_lane(changes: Changes, lane: list[Item], before: list[dict[str, Any]] | None = None,
             ) -> list[dict[str, Any]]:
    """Run a lane's items in order, after the results ``before`` of its earlier items; after a
    failure the rest are skipped."""
    results: list[dict[str, Any]] = list(before or [])
    for item in lane:
        if results and results[-1]["outcome"] != "done":
            results.append({"outcome": "skipped"})
            continue
        try:
            answer = item.run(changes)
        except Exception as exc:  # noqa: BLE001 - every error becomes this item's result
            results.append(item_result(item, exc))
            continue
        results.append(item_result(item, answer))
    return results


def item_result(item: Item, answer: Any) -> dict[str, Any]:
    """An item's result from its answer (None: 204) or the exception it raised."""
    if isinstance(answer, Exception):
        status, error = error_status(answer, f"batch {item.what}")
        return {"outcome": "failed", "status": status, "error": error}
    return {"outcome": "done", "status": 204 if answer is None else 200,
            "answer": None if answer is None else to_dict(answer)}


def run_batch(changes: Changes, lanes: list[list[Item]]) -> list[list[dict[str, Any]]]:
    """Run every lane, at the same time; the results in the lanes' order. Each lane's first broker
    item runs with the others' (:func:`_broker_step`), between what comes before and after it."""
    if len(lanes) <= 1:
        return [run_lane(changes, lane) for lane in lanes]
    cuts = [next((j for j, item in enumerate(lane) if item.broker is not None), None) for lane in lanes]
    ids = [lane[j].broker_id for lane, j in zip(lanes, cuts) if j is not None]
    if not ids or len(set(ids)) != len(ids):  # one broker in two lanes: its items take turns
        return _each_lane(lambda k: run_lane(changes, lanes[k]), len(lanes))
    heads = _each_lane(lambda k: run_lane(changes, lanes[k][:cuts[k]]), len(lanes))
    ready = {k: lanes[k][j] for k, j in enumerate(cuts)
             if j is not None and all(r["outcome"] == "done" for r in heads[k])}
    for k, result in _broker_step(changes, ready).items():
        heads[k].append(result)
    return _each_lane(lambda k: run_lane(changes, lanes[k][len(heads[k]):], heads[k]), len(lanes))


def _broker_step(changes: Changes, items: dict[int, Item]) -> dict[int, dict[str, Any]]:
    """The broker items (by lane), in one step: the deletes together, then the puts together."""
    results: dict[int, dict[str, Any]] = {}
    for op, many in (("delete_broker", changes.delete_brokers), ("put_broker", changes.put_brokers)):
        lanes = [k for k, item in items.items() if item.op == op]
        if not lanes:
            continue
        try:
            answers: list[Any] = many([items[k].broker for k in lanes])  # type: ignore[misc]
        except Exception as exc:  # noqa: BLE001 - a bug: each of its items says so
            answers = [exc] * len(lanes)
        for k, answer in zip(lanes, answers, strict=True):
            results[k] = item_result(items[k], answer)
    return results


def _each_lane(work: Callable[[int], list[dict[str, Any]]], count: int) -> list[list[dict[str, Any]]]:
    """``work(k)`` for every lane k, a thread each (a lane may wait for a broker of its own).
    :func:`run_lane` makes every item's error its result, so an error here is a bug: the first is
    raised once every lane is done."""
    lanes = each(work, range(count), threads=count, name="batch")
    for lane in lanes:
        if isinstance(lane, Exception):
            raise lane
    return lanes  # type: ignore[return-value] - no error among them
