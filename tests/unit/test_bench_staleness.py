"""benchmarks/staleness.py in a throw-away git repository: a results file is stale once a later
commit touches the code its study measures, not when other code changes; a run without a commit,
or with one the clone does not have, is flagged as unknown; the report lists stale tables."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

from benchmarks import staleness


def git(root: Path, *args: str) -> str:
    return subprocess.run(["git", *args], cwd=root, check=True, capture_output=True, text=True).stdout.strip()


def commit(root: Path, path: str, text: str) -> str:
    (root / path).parent.mkdir(parents=True, exist_ok=True)
    (root / path).write_text(text)
    git(root, "add", path)
    git(root, "-c", "user.name=t", "-c", "user.email=t@example.org", "commit", "-q", "-m", f"edit {path}")
    return git(root, "rev-parse", "--short", "HEAD")


def test_stale_only_when_the_measured_code_changed(tmp_path: Path) -> None:
    git(tmp_path, "init", "-q")
    measured = commit(tmp_path, "engine/context_broker/app.py", "v1")
    data = {"machine": {"commit": measured + "+changes"}}
    assert staleness.stale_note(tmp_path, "context_broker", data) is None
    commit(tmp_path, "fleet/planner/x.py", "other code")
    assert staleness.stale_note(tmp_path, "context_broker", data) is None
    commit(tmp_path, "engine/context_broker/app.py", "v2")
    note = staleness.stale_note(tmp_path, "context_broker", data)
    assert note is not None and "1 commit(s) after " + measured in note
    assert "plantkg-bench context_broker" in note


def test_unknown_commits_are_flagged_not_guessed(tmp_path: Path) -> None:
    git(tmp_path, "init", "-q")
    commit(tmp_path, "kg/a.py", "x")
    assert "records no commit" in str(staleness.stale_note(tmp_path, "validate", {"machine": {}}))
    assert "not in this checkout" in str(staleness.stale_note(tmp_path, "validate",
                                                               {"machine": {"commit": "0123abc"}}))
    assert staleness.stale_note(tmp_path, "no-such-study", {"machine": {"commit": "0123abc"}}) is None


def test_every_reported_study_names_what_it_measures() -> None:
    from benchmarks import report

    assert {name for name, _t, _i in report.SECTIONS} <= set(staleness.MEASURES)
    root = Path(__file__).resolve().parents[2]
    for paths in staleness.MEASURES.values():
        assert all((root / p).exists() for p in paths), paths


def test_the_report_lists_a_table_without_a_commit(tmp_path: Path) -> None:
    from benchmarks import report

    results = tmp_path / "results"
    results.mkdir()
    (results / "validate.json").write_text(json.dumps({"command": "x", "machine": {"cpus": 2}}))
    (results / "validate.md").write_text("# validate\n\nCommand: `x`\n\n| a |\n|---|\n| 1 |\n")
    text = report.render(results, tmp_path)
    assert "Tables that may not describe the current code" in text
    assert text.count("records no commit") == 2  # in the list at the top and above the table


def test_comments_and_docstrings_do_not_make_a_table_stale(tmp_path: Path) -> None:
    git(tmp_path, "init", "-q")
    path = "engine/context_broker/app.py"
    measured = commit(tmp_path, path, '"""The app."""\n\ndef f(x):\n    """Twice x."""\n    return 2 * x\n')
    data = {"machine": {"commit": measured}}
    commit(tmp_path, path, '"""The app, said otherwise."""\n\n# a comment citing 3.4 ms\n'
                           'def f(x):\n    """Twice x, measured."""\n    return 2 * x  # fast\n')
    assert staleness.stale_note(tmp_path, "context_broker", data) is None
    commit(tmp_path, path, '"""The app."""\n\ndef f(x):\n    return 3 * x\n')
    note = staleness.stale_note(tmp_path, "context_broker", data)
    assert note is not None and "2 commit(s) after " + measured in note


def test_a_changed_file_that_is_not_python_counts(tmp_path: Path) -> None:
    git(tmp_path, "init", "-q")
    measured = commit(tmp_path, "shapes/plant.ttl", "# shapes v1\n")
    commit(tmp_path, "shapes/plant.ttl", "# shapes v2\n")
    assert staleness.stale_note(tmp_path, "validate", {"machine": {"commit": measured}}) is not None


def test_a_new_or_broken_python_file_counts(tmp_path: Path) -> None:
    git(tmp_path, "init", "-q")
    measured = commit(tmp_path, "kg/a.py", "x = 1\n")
    data = {"machine": {"commit": measured}}
    commit(tmp_path, "kg/b.py", "y = 2\n")
    assert staleness.stale_note(tmp_path, "validate", data) is not None
    git(tmp_path, "rm", "-q", "kg/b.py")
    git(tmp_path, "-c", "user.name=t", "-c", "user.email=t@example.org", "commit", "-q", "-m", "rm")
    assert staleness.stale_note(tmp_path, "validate", data) is None  # back to the measured code
    commit(tmp_path, "kg/a.py", "x = (\n")
    assert staleness.stale_note(tmp_path, "validate", data) is not None
