"""The console script reads plain apply/destroy lines itself (engine.control.entry), exactly as
click reads them; any other line is the command line's. Cases as data, each held to click's own
parse of the same line."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.cli.apply import apply_command
from engine.cli.destroy import destroy_command
from engine.control.entry import main, read

# (argv, what the entry point reads: (verb, files, agents, owner, options) or None)
READ = [
    (["apply", "p.ttl"], ("apply", ("p.ttl",), None, None, {"yes": False, "parallelism": 8, "format": "text", "prune": False})),
    (["apply", "--yes", "--agents", "a.toml", "p.ttl", "q.ttl"],
     ("apply", ("p.ttl", "q.ttl"), "a.toml", None, {"yes": True, "parallelism": 8, "format": "text", "prune": False})),
    (["apply", "p.ttl", "-y", "--agents=a.toml", "--parallelism", "3", "--owner", "line-2", "--prune", "--format", "json"],
     ("apply", ("p.ttl",), "a.toml", "line-2", {"yes": True, "parallelism": 3, "format": "json", "prune": True})),
    (["apply", "--parallelism=64", "--owner=x", "p.ttl"],
     ("apply", ("p.ttl",), None, "x", {"yes": False, "parallelism": 64, "format": "text", "prune": False})),
    (["apply", "--agents", "one.toml", "--agents", "two.toml", "p.ttl"],  # the last one wins, as in click
     ("apply", ("p.ttl",), "two.toml", None, {"yes": False, "parallelism": 8, "format": "text", "prune": False})),
    (["destroy", "--yes", "p.ttl"], ("destroy", ("p.ttl",), None, None, {"yes": True, "parallelism": 8, "format": "text"})),
    # not plain: the command line decides (and reports what is wrong)
    (["plan", "p.ttl"], None),
    (["apply"], None),
    (["apply", "--help"], None),
    (["apply", "p.ttl", "--local"], None),
    (["apply", "p.ttl", "--agents"], None),
    (["apply", "p.ttl", "--parallelism", "0"], None),
    (["apply", "p.ttl", "--parallelism", "65"], None),
    (["apply", "p.ttl", "--parallelism", "many"], None),
    (["apply", "p.ttl", "--format", "yaml"], None),
    (["apply", "p.ttl", "--yes=true"], None),
    (["apply", "p.ttl", "--owner="], None),
    (["apply", "--", "p.ttl"], None),
    (["apply", "p.ttl", "-v"], None),
    (["destroy", "p.ttl", "--prune"], None),
    ([], None),
]


@pytest.mark.parametrize(("argv", "expected"), READ, ids=[" ".join(a) or "(none)" for a, _ in READ])
def test_the_entry_point_reads_plain_lines_only(argv: list[str], expected: tuple | None) -> None:  # type: ignore[type-arg]
    assert read(argv) == expected


@pytest.mark.parametrize(("argv", "expected"), [c for c in READ if c[1] is not None],
                         ids=[" ".join(a) for a, e in READ if e is not None])
def test_what_it_reads_is_what_click_reads(argv: list[str], expected: tuple) -> None:  # type: ignore[type-arg]
    command = apply_command if argv[0] == "apply" else destroy_command
    params = command.make_context(argv[0], list(argv[1:])).params
    served = read(argv)
    assert served is not None
    _verb, files, agents, owner, options = served
    assert params["files"] == files and params["owner"] == owner
    assert (str(params["agents_file"]) if params["agents_file"] else None) == agents
    assert params["yes"] == options["yes"] and params["parallelism"] == options["parallelism"]
    assert params["fmt"] == options["format"] and params.get("prune", False) == options.get("prune", False)


def test_without_a_server_the_command_line_runs_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setenv("PLANTKG_RUN_DIR", str(tmp_path / "run"))
    missing = tmp_path / "missing.ttl"
    assert main(["apply", "--yes", str(missing)]) == 2  # the command line's own error, exit code
    err = capsys.readouterr().err
    assert "missing.ttl: no such file" in err and "Traceback" not in err
