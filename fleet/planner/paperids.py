"""The paper's ids of a sub-task sent to a paper-channel vehicle: UUIDs (the channels' schema
wants them), derived from the sub-task's orderId, so a resend after a restart names the same
items (the vehicle ignores an item id it has seen) and a later attempt names new ones.

A sub-task ``<orderId>`` is the paper's task ``task_uuid(orderId)``: motion item(s) ``motion_uuid``,
then one action item per action ``action_uuid(orderId, i)``, then the wait that ends the task
``end_uuid`` (unless the sub-task's last action is a wait already).
"""

from __future__ import annotations

import uuid

_NS = uuid.uuid5(uuid.NAMESPACE_URL, "https://w3id.org/plantkg/planner#paper")


def _id(*parts: object) -> str:
    return str(uuid.uuid5(_NS, "/".join(map(str, parts))))


def task_uuid(order_id: str) -> str:
    return _id(order_id, "task")


def point_uuid(station: str) -> str:
    return _id("point", station)


def motion_uuid(order_id: str, index: int = 0) -> str:
    return _id(order_id, "motion", index)


def action_uuid(order_id: str, index: int) -> str:
    return _id(order_id, "action", index)


def end_uuid(order_id: str) -> str:
    return _id(order_id, "end")


def first_sequence(order_id: str) -> int:
    """The sequence of the sub-task's first item: below 2**28, so its items stay below 2**31."""
    return int(task_uuid(order_id).replace("-", "")[:7], 16) + 1


def item_ids(order_id: str, actions: int, motions: int = 1) -> frozenset[str]:
    """Every item id a sub-task of ``motions`` motions and ``actions`` actions may use."""
    return frozenset([motion_uuid(order_id, i) for i in range(motions)]
                     + [action_uuid(order_id, i) for i in range(actions)] + [end_uuid(order_id)])
