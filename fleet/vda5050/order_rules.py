"""The structural rules of a VDA 5050 order and of an order update (section 6.6), as pure checks.

The schema says which fields exist; these say how they fit together: edges = nodes - 1, sequence
ids interleave (node n, edge n+1, node n+2, ...), each edge joins the nodes around it, the base
(released) comes before the horizon, action ids are unique. Both the simulated vehicle (to refuse
an order with ``validationError``) and a master (before sending) use them.
"""

from __future__ import annotations

from fleet.vda5050.messages import Order


def structure_problems(order: Order) -> list[str]:
    """Every broken rule of ``order``, each naming the node or edge; empty when it is well formed."""
    found: list[str] = []
    nodes, edges = order.nodes, order.edges
    if not nodes:
        return ["nodes: an order has at least one node"]
    if len(edges) != len(nodes) - 1:
        found.append(f"edges: {len(edges)} edges for {len(nodes)} nodes, expected {len(nodes) - 1}")
        return found
    if not nodes[0].released:
        found.append(f"nodes/0 ({nodes[0].node_id}): the first node must be released")
    for i, edge in enumerate(edges):
        before, after = nodes[i], nodes[i + 1]
        if edge.sequence_id != before.sequence_id + 1 or after.sequence_id != edge.sequence_id + 1:
            found.append(f"edges/{i} ({edge.edge_id}): sequenceId {edge.sequence_id} must lie between "
                         f"node {before.sequence_id} and node {after.sequence_id}, one apart")
        if edge.start_node_id != before.node_id or edge.end_node_id != after.node_id:
            found.append(f"edges/{i} ({edge.edge_id}): joins {edge.start_node_id} -> {edge.end_node_id}, "
                         f"but the nodes around it are {before.node_id} -> {after.node_id}")
        if edge.released != after.released:
            found.append(f"edges/{i} ({edge.edge_id}): released={edge.released} but its end node "
                         f"{after.node_id} has released={after.released}")
    for i in range(1, len(nodes)):
        if nodes[i].released and not nodes[i - 1].released:
            found.append(f"nodes/{i} ({nodes[i].node_id}): released after an unreleased node (base must precede horizon)")
    seen: set[str] = set()
    for item in (*nodes, *edges):
        for action in item.actions:
            if action.action_id in seen:
                found.append(f"actionId {action.action_id!r} is used twice in the order")
            seen.add(action.action_id)
    return found


def base_end(order: Order) -> int:
    """Index of the last released node."""
    last = 0
    for i, node in enumerate(order.nodes):
        if node.released:
            last = i
    return last
