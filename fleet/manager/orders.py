"""VDA 5050 orders from a list of nodes: built, checked against the schema and the order rules.

A node is a name and a position on a map, with actions to run there. ``plantkg fleet order
SERIAL NODE...`` names nodes as

- ``STATION`` — a station of the map (``--map``; default: the simulator's 40 x 20 m hall),
- ``NAME@X,Y`` — any point of the map,
- either followed by ``:ACTION[,ACTION...]`` (``pick-1:pick``, ``n1@2,0:pick,drop``).

Every node is released (the whole order is base), edges join consecutive nodes, sequence ids
interleave (node 0, edge 1, node 2, ...), actions are HARD blocking with ids
``<orderId>-<node>-<i>``. Functions are pure; :func:`order_json` raises :class:`OrderError`
naming the node and what is wrong.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from typing import Any

from fleet.discovery.errors import DiscoveryError
from fleet.sim.map import MapError, SiteMap
from fleet.vda5050 import schemas
from fleet.vda5050.errors import SchemaError
from fleet.vda5050.messages import Action, BlockingType, Edge, Node, NodePosition, Order
from fleet.vda5050.order_rules import structure_problems

_NODE = re.compile(r"^(?P<name>[^@:\s]+)(?:@(?P<x>[-+0-9.eE]+),(?P<y>[-+0-9.eE]+))?(?::(?P<actions>[A-Za-z0-9_,]+))?$")
MAX_NODES = 1000


class OrderError(DiscoveryError):
    """An order that cannot be built: which node, what is wrong."""


@dataclass(frozen=True)
class NodeSpec:
    node_id: str
    x: float
    y: float
    map_id: str
    actions: tuple[str, ...] = ()

    def to_json(self) -> dict[str, Any]:
        return {"nodeId": self.node_id, "x": self.x, "y": self.y, "mapId": self.map_id,
                "actions": list(self.actions)}

    @classmethod
    def from_json(cls, data: Any, index: int) -> NodeSpec:
        where = f"nodes[{index}]"
        if not isinstance(data, dict):
            raise OrderError(f"{where}: expected an object with nodeId, x, y, mapId, got {data!r}"[:300])
        node_id, map_id, actions = data.get("nodeId"), data.get("mapId"), data.get("actions", [])
        if not isinstance(node_id, str) or not node_id:
            raise OrderError(f"{where}.nodeId: expected a non-empty string, got {node_id!r}"[:300])
        if not isinstance(map_id, str) or not map_id:
            raise OrderError(f"{where}.mapId: expected a non-empty string, got {map_id!r}"[:300])
        coords = []
        for axis in ("x", "y"):
            value = data.get(axis)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise OrderError(f"{where}.{axis}: expected a finite number, got {value!r}"[:300])
            coords.append(float(value))
        if not isinstance(actions, list) or not all(isinstance(a, str) and a for a in actions):
            raise OrderError(f"{where}.actions: expected a list of action types, got {actions!r}"[:300])
        return cls(node_id, coords[0], coords[1], map_id, tuple(actions))


def parse_node(text: str, site: SiteMap) -> NodeSpec:
    """One ``NODE`` argument of ``plantkg fleet order``."""
    match = _NODE.match(text)
    if match is None:
        raise OrderError(f"node {text!r}: expected STATION, NAME@X,Y, either followed by :ACTION[,ACTION]",
                         hint="e.g. pick-1:pick  or  n1@2.5,4:drop")
    name, actions = match["name"], tuple(a for a in (match["actions"] or "").split(",") if a)
    if match["x"] is not None:
        try:
            x, y = float(match["x"]), float(match["y"])
        except ValueError:
            raise OrderError(f"node {text!r}: {match['x']},{match['y']} is not a point X,Y") from None
        return NodeSpec(name, x, y, site.map_id, actions)
    try:
        station = site.station(name)
    except MapError as exc:
        raise OrderError(f"node {text!r}: {exc.message}",
                         hint="name a station of the map, or give a point as NAME@X,Y") from None
    return NodeSpec(name, station.x, station.y, site.map_id, actions)


def build_order(order_id: str, nodes: list[NodeSpec]) -> Order:
    if not nodes:
        raise OrderError("an order needs at least one node")
    if len(nodes) > MAX_NODES:
        raise OrderError(f"an order of {len(nodes)} nodes: at most {MAX_NODES}")
    built = []
    for i, spec in enumerate(nodes):
        actions = tuple(Action(kind, f"{order_id}-{spec.node_id}-{j}", BlockingType.HARD)
                        for j, kind in enumerate(spec.actions))
        built.append(Node(spec.node_id, 2 * i, True, actions, NodePosition(spec.x, spec.y, spec.map_id)))
    edges = tuple(Edge(f"{a.node_id}-{b.node_id}", 2 * i + 1, a.node_id, b.node_id)
                  for i, (a, b) in enumerate(zip(nodes, nodes[1:])))
    order = Order(order_id, 0, tuple(built), edges)
    problems = structure_problems(order)
    if problems:
        raise OrderError(f"order {order_id!r}: " + "; ".join(problems))
    return order


def order_json(order: Order, header: dict[str, Any]) -> dict[str, Any]:
    """The wire form of ``order``, checked against the official schema before it is sent."""
    wire = order.to_json(header)
    try:
        schemas.check("order", wire)
    except SchemaError as exc:
        raise OrderError(f"order {order.order_id!r}: {exc.message}") from None
    return wire
