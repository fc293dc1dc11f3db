"""Task chains that never end (OnDone cycles) and tasks that can never start (waiting cycles).

A task's follow-ups are the tasks in its own OnDone and in the OnDone of its pickup and delivery
steps. The LoTLan authors use such cycles for "infinite" processes (``OnDone helloTask`` in
helloTask itself); the fleet manager refuses them, because a material flow it accepts must finish
(its jobs are started from the operators' screens, and ``Repeat N`` runs a transport N times).
Each cycle is reported once (per strongly connected group of tasks), at the task whose OnDone
closes it, with the whole chain spelled out.

A task whose TriggeredBy requires ``other.IsDone`` waits for ``other``; a cycle of such waits
(``TriggeredBy helloTask.IsDone`` in helloTask itself) is a deadlock: none of its tasks can
start. "Requires" is judged conservatively: a state under ``!``, in a comparison or on one side
of an ``or`` is not required, both sides of an ``and`` are.
"""

from __future__ import annotations

from collections.abc import Callable

from fleet.lotlan.model import And, Expr, Or, Pos, Task, TaskAttribute


def follow_ups(task: Task) -> tuple[tuple[str, str], ...]:
    """The tasks started when ``task`` is done, each with where the OnDone is written."""
    edges = [(name, "") for name in task.on_done]
    for use in (task.pickup, task.delivery):
        edges += [(name, f"OnDone of step {use.step.name}") for name in use.step.on_done]
    return tuple(dict.fromkeys(edges))


def find_cycles(tasks: list[Task]) -> list[list[tuple[str, str]]]:
    """One cycle per cyclic group of tasks: [(task, ""), (next, via), ..., (task, via)]."""
    edges = {t.name: follow_ups(t) for t in tasks}
    graph = {name: [n for n, _ in targets] for name, targets in edges.items()}
    found = []
    for group in _strongly_connected(graph):
        first = group[0]
        if len(group) == 1 and first not in graph.get(first, ()):
            continue
        path = _path_back(graph, first, set(group))
        cycle = [(first, "")]
        for here, there in zip(path, path[1:]):
            cycle.append((there, next(via for n, via in edges[here] if n == there)))
        found.append(cycle)
    return found


def check_on_done_cycles(error: Callable[[Pos, str], None], tasks: list[Task]) -> None:
    by_name = {t.name: t for t in tasks}
    for cycle in find_cycles(tasks):
        chain = cycle[0][0] + "".join(f" -> {name}" + (f" ({via})" if via else "") for name, via in cycle[1:])
        error(by_name[cycle[-2][0]].at, f"OnDone cycle without end: {chain}; these tasks start each "
              "other forever and never finish: remove one OnDone of the chain (to run a transport "
              "several times use Repeat N)")


def required_tasks(expr: Expr | None) -> frozenset[str]:
    """Tasks whose IsDone must hold for ``expr`` to hold."""
    if isinstance(expr, TaskAttribute) and expr.attribute == "IsDone":
        return frozenset((expr.task,))
    if isinstance(expr, And):
        return required_tasks(expr.left) | required_tasks(expr.right)
    if isinstance(expr, Or):
        return required_tasks(expr.left) & required_tasks(expr.right)
    return frozenset()  # a literal, an event, a comparison, a negation: no task state required


def check_waiting_cycles(error: Callable[[Pos, str], None], tasks: list[Task]) -> None:
    """Report each group of tasks that wait (TriggeredBy ... .IsDone) for each other."""
    graph = {t.name: sorted(required_tasks(t.triggered_by)) for t in tasks}
    by_name = {t.name: t for t in tasks}
    for group in _strongly_connected(graph):
        first = group[0]
        if len(group) == 1 and first not in graph[first]:
            continue
        cycle = _path_back(graph, first, set(group))
        waits = ", ".join(f"{a} waits for {b}.IsDone" for a, b in zip(cycle, cycle[1:]))
        error(by_name[first].triggered_by.at, f"TriggeredBy cycle: {waits}; none of these tasks can "
              "ever start: remove the wait on a task of the cycle")


def _strongly_connected(graph: dict[str, list[str]]) -> list[list[str]]:
    """Tarjan's algorithm, iterative; groups in discovery order, members in source order."""
    order = {name: i for i, name in enumerate(graph)}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    groups: list[list[str]] = []
    counter = 0
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(graph[root]))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            advanced = False
            for child in children:
                if child not in graph:
                    continue
                if child not in index:
                    index[child] = low[child] = counter
                    counter += 1
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(graph[child])))
                    advanced = True
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            if advanced:
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
            if low[node] == index[node]:
                group = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    group.append(member)
                    if member == node:
                        break
                groups.append(sorted(group, key=order.__getitem__))
    return sorted(groups, key=lambda g: order[g[0]])


def _path_back(graph: dict[str, list[str]], start: str, group: set[str]) -> list[str]:
    """A shortest path start -> ... -> start inside the group (breadth first)."""
    previous: dict[str, str] = {}
    queue = [start]
    while queue:
        node = queue.pop(0)
        for child in graph[node]:
            if child not in group:
                continue
            if child == start:
                path = [node]
                while path[-1] != start:
                    path.append(previous[path[-1]])
                return [start] + path[::-1][1:] + [start] if node != start else [start, start]
            if child not in previous:
                previous[child] = node
                queue.append(child)
    return [start, start]
