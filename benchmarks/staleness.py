"""Whether a results file still measures the code in this checkout.

Each study measures some code (:data:`MEASURES`: paths of the repository). A results file records
the commit it ran at (``machine.commit``, ``+changes`` when the tree had uncommitted edits). If
commits after that one changed the measured paths, the table is stale: :func:`stale_note` says so,
naming how many commits and the command that measures it again. Changes to comments and docstrings
alone do not count (:func:`code_differs` compares the Python files' syntax trees): a comment that
cites a figure must not make the figure stale. ``plantkg-bench report`` puts the
note above the table and lists every stale table at the top of RESULTS.md, so no figure passes for
the current code when it is not.
"""

from __future__ import annotations

import ast
import subprocess
from pathlib import Path
from typing import Any

#: study -> the repository paths whose code it measures
MEASURES: dict[str, tuple[str, ...]] = {
    "deploy": ("engine/apply.py", "engine/apply_calls.py", "engine/agent", "engine/drivers",
               "engine/process.py", "engine/pipeline.py", "engine/reasoning",
               "kg", "shapes", "ontology", "benchmarks/bench_deploy.py"),
    "load": ("engine/apply.py", "engine/apply_calls.py", "engine/agent", "engine/drivers",
             "engine/process.py", "benchmarks/bench_load.py",
             "benchmarks/mqtt_ready.py"),
    "replan": ("kg", "shapes", "ontology", "engine/pipeline.py", "engine/derive.py", "engine/plan.py",
               "engine/incremental/replan.py", "engine/reasoning/reason.py", "engine/reasoning/rules_fast.py",
               "engine/reasoning/rules_delta.py"),
    "bridge": ("engine/bridge_worker", "engine/drivers"),
    "durability": ("engine/bridge_worker", "engine/drivers"),
    "web": ("engine/web",),
    "context_broker": ("engine/context_broker",),
    "bridge_ngsi": ("engine/bridge_worker", "engine/context_broker"),
    "fleet_join": ("fleet/manager", "fleet/discovery", "fleet/model", "engine/apply.py", "engine/agent"),
    "fleet_tasks": ("fleet/planner", "fleet/sim"),
    "cli": ("engine/cli",),
    "security": ("engine/drivers/mosquitto", "engine/security", "tools/loadgen", "benchmarks/loadgen.py"),
    "kafka_cluster": ("engine/drivers/kafka", "engine/derived/kafka_cluster.py", "engine/apply.py", "engine/agent",
                      "engine/derived/bridge_pairs.py"),
    "validate": ("kg", "shapes"),
    "reason": ("engine/reasoning/reason.py", "engine/reasoning/rules_fast.py", "engine/reasoning/rules_owlready.py", "ontology"),
}


def recorded_commit(data: dict[str, Any]) -> str | None:
    machine = data.get("machine")
    commit = machine.get("commit") if isinstance(machine, dict) else None
    if not isinstance(commit, str) or not commit.strip() or commit.startswith("?"):
        return None
    return commit.split("+", 1)[0].strip()


def commits_since(root: Path, commit: str, paths: tuple[str, ...]) -> int | None:
    """How many commits after ``commit`` (up to HEAD) touch ``paths``; None when git cannot tell
    (no git, not a repository, or a commit this clone does not have)."""
    try:
        done = subprocess.run(["git", "rev-list", "--count", f"{commit}..HEAD", "--", *paths], cwd=root,
                              capture_output=True, text=True, timeout=30, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return None
    if done.returncode != 0 or not done.stdout.strip().isdigit():
        return None
    return int(done.stdout.strip())


def code_differs(root: Path, commit: str, paths: tuple[str, ...]) -> bool:
    """Whether the code under ``paths`` differs between ``commit`` and HEAD in more than comments
    and docstrings: a changed Python file counts only if its syntax tree (docstrings left out)
    changed; any other changed file (shapes, ontology) counts. True when git cannot tell."""
    try:
        done = subprocess.run(["git", "diff", "--name-only", commit, "HEAD", "--", *paths], cwd=root,
                              capture_output=True, text=True, timeout=30, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return True
    if done.returncode != 0:
        return True
    for name in done.stdout.split():
        if not name.endswith(".py"):
            return True
        before, after = _show(root, commit, name), _show(root, "HEAD", name)
        tree = _code(before) if before is not None else None
        if tree is None or after is None or tree != _code(after):
            return True
    return False


def _show(root: Path, commit: str, name: str) -> str | None:
    """The file ``name`` at ``commit`` (None: it does not exist there, or git failed)."""
    try:
        done = subprocess.run(["git", "show", f"{commit}:{name}"], cwd=root, capture_output=True,
                              text=True, timeout=30, check=False)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return done.stdout if done.returncode == 0 else None


def _code(source: str) -> str | None:
    """The syntax tree of ``source`` without docstrings, as text (None: not valid Python)."""
    try:
        tree = ast.parse(source)
    except SyntaxError:
        return None
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                and body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)):
            node.body = body[1:] or [ast.Pass()]
    return ast.dump(tree)


def stale_note(root: Path, name: str, data: dict[str, Any]) -> str | None:
    """A sentence when the table of study ``name`` may not describe the current code, else None."""
    paths = MEASURES.get(name)
    if not paths:
        return None
    commit = recorded_commit(data)
    if commit is None:
        return (f"**Stale?** This run records no commit, so it cannot be matched to the code; re-run "
                f"`plantkg-bench {name}`.")
    count = commits_since(root, commit, paths)
    if count is None:
        return (f"**Stale?** Its commit {commit} is not in this checkout's history, so it cannot be "
                f"matched to the code; re-run `plantkg-bench {name}`.")
    if count == 0 or not code_differs(root, commit, paths):
        return None
    return (f"**Stale:** {count} commit(s) after {commit} touched the code it measures "
            f"({', '.join(paths)}); re-run `plantkg-bench {name}`.")


__all__ = ["MEASURES", "code_differs", "commits_since", "recorded_commit", "stale_note"]
