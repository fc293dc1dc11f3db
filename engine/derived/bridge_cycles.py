"""Refuse bridges that forward a topic around a cycle of three or more brokers (pure).

A bridge hands on every message of its topics that reaches its source broker, including messages
another bridge delivered there. Mosquitto (``try_private``) and the bridge workers only keep a
message from going straight back over the connection it came by, which is why a pair bridged both
ways (one connection, ``topic t both``) is safe. Around a cycle A -> B -> C -> A nothing stops it:
one QoS-1 publish was delivered ~36,000 times per broker in 5 s (issue 15).

What loops is a *topic*: the directed bridges ``derive`` found (asserted ``pk:bridgesTo`` and
those rule R1 derives, any mix of Mosquitto, Kafka and context brokers) each forward a set of topic
names, and a message goes around only if every hop of the cycle forwards its topic. So, per topic
name, the graph of brokers joined by the hops that forward it must have no *simple* cycle of three
or more brokers. A -> B -> A (a two-way pair) is allowed, and so is a chain of two-way pairs
(A <-> B <-> C): a message reaching C cannot come back except over the connection it came by.

Why here and not a rule in Turtle: the relation is per topic (broker, broker, topic: ternary, which
neither OWL nor SWRL can hold) and the test is "a simple cycle of three or more", which neither a
transitive property nor a SPARQL property path can tell from a chain of two-way pairs (both reach
themselves). The graph is tiny; the test is linear: a one-way hop A -> B on a cycle (B reaches A)
closes a simple cycle of length >= 3 with the shortest path back; a component of two-way hops only
loops if, seen undirected, it has a cycle.
"""

from __future__ import annotations

from collections import defaultdict, deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from engine.derived.bridge_pairs import DirectedBridge
from engine.errors import EngineError

__all__ = ["BridgeCycle", "BridgeCycleError", "check_no_cycles", "find_cycle", "find_cycles"]


@dataclass(frozen=True)
class BridgeCycle:
    """Brokers (ids, in forwarding order, the first repeated implicitly at the end) that hand the
    ``topics`` round, and for each hop whether the plant asserts it (else rule R1 derives it)."""

    brokers: tuple[str, ...]
    topics: tuple[str, ...]
    asserted: tuple[bool, ...]

    def describe(self) -> str:
        hops = []
        for i, source in enumerate(self.brokers):
            target = self.brokers[(i + 1) % len(self.brokers)]
            how = "pk:bridgesTo" if self.asserted[i] else "derived by rule R1"
            hops.append(f"{source} -> {target} ({how})")
        path = " -> ".join((*self.brokers, self.brokers[0]))
        return f"{path} forwards {', '.join(self.topics)} round the cycle: {'; '.join(hops)}"


class BridgeCycleError(EngineError):
    """Bridges forward a topic around a cycle of three or more brokers: each message would loop."""

    def __init__(self, cycles: Sequence[BridgeCycle]) -> None:
        lines = "\n  ".join(c.describe() for c in cycles)
        super().__init__(
            f"bridge cycle: a message would go round these brokers for ever (each bridge re-forwards "
            f"what another delivered; only a pair bridged both ways is loop-free):\n  {lines}",
            hint="break each cycle: remove one pk:bridgesTo of it, or take the topic off one broker of "
                 "it (pk:hasTopic); for a hop rule R1 derives, move the publisher or the subscriber "
                 "of the topic to another broker. Nothing was applied.")
        self.cycles = tuple(cycles)


def find_cycle(edges: Iterable[tuple[str, str]]) -> tuple[str, ...] | None:
    """A simple cycle of three or more nodes in the directed graph ``edges`` (in order, starting
    at its smallest node), or None. Two-way pairs (a -> b and b -> a) alone are not a cycle."""
    succ: dict[str, set[str]] = defaultdict(set)
    for a, c in edges:
        if a != c:
            succ[a].add(c)
    for a in sorted(succ):
        for c in sorted(succ[a]):
            if a in succ.get(c, ()):
                continue  # a two-way hop: below
            back = _shortest_path(succ, c, a)
            if back is not None:  # a -> c, then c ... a: simple, and >= 3 as c -> a is no hop
                return _rotate((a, *back[:-1]))
    two_way = {a: {c for c in cs if a in succ.get(c, ())} for a, cs in succ.items()}
    return _undirected_cycle(two_way)


def find_cycles(bridges: Iterable[DirectedBridge]) -> list[BridgeCycle]:
    """Per topic name, a forwarding cycle of three or more brokers; topics that go round the same
    cycle are grouped. Sorted, so the message is the same on every run."""
    bridges = list(bridges)
    asserted = {(b.source, b.target): b.asserted for b in bridges}
    by_topic: dict[str, set[tuple[str, str]]] = defaultdict(set)
    for b in bridges:
        for topic in b.topics:
            by_topic[topic].add((b.source, b.target))
    found: dict[tuple[str, ...], list[str]] = defaultdict(list)
    for topic in sorted(by_topic):
        cycle = find_cycle(by_topic[topic])
        if cycle is not None:
            found[cycle].append(topic)
    return [BridgeCycle(cycle, tuple(topics),
                        tuple(asserted[(cycle[i], cycle[(i + 1) % len(cycle)])] for i in range(len(cycle))))
            for cycle, topics in sorted(found.items())]


def check_no_cycles(bridges: Iterable[DirectedBridge]) -> None:
    """Raise :class:`BridgeCycleError` naming every cycle :func:`find_cycles` finds."""
    cycles = find_cycles(bridges)
    if cycles:
        raise BridgeCycleError(cycles)


def _shortest_path(succ: dict[str, set[str]], start: str, goal: str) -> list[str] | None:
    """Nodes from ``start`` to ``goal`` (both included) along ``succ``, breadth first, or None."""
    before: dict[str, str | None] = {start: None}
    queue = deque([start])
    while queue:
        node = queue.popleft()
        if node == goal:
            path = [node]
            while before[path[-1]] is not None:
                path.append(before[path[-1]])  # type: ignore[arg-type]
            return path[::-1]
        for nxt in sorted(succ.get(node, ())):
            if nxt not in before:
                before[nxt] = node
                queue.append(nxt)
    return None


def _undirected_cycle(adj: dict[str, set[str]]) -> tuple[str, ...] | None:
    """A cycle of the undirected graph ``adj`` (symmetric), found by depth-first search."""
    parent: dict[str, str | None] = {}
    for root in sorted(adj):
        if root in parent:
            continue
        parent[root] = None
        stack = [(root, iter(sorted(adj[root])))]
        while stack:
            node, children = stack[-1]
            nxt = next(children, None)
            if nxt is None:
                stack.pop()
            elif nxt not in parent:
                parent[nxt] = node
                stack.append((nxt, iter(sorted(adj[nxt]))))
            elif nxt != parent[node] and any(n == nxt for n, _ in stack):
                path = [n for n, _ in stack]
                return _rotate(tuple(path[path.index(nxt):]))
    return None


def _rotate(cycle: tuple[str, ...]) -> tuple[str, ...]:
    i = cycle.index(min(cycle))
    return cycle[i:] + cycle[:i]
