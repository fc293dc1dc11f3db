"""The command line starts at once: ``plantkg --help`` and ``plantkg plan`` do not import what they
do not use (the agent's HTTP server, Flask, rdflib's SPARQL engine, pySHACL, the broker clients).

Each case runs ``engine.cli.main`` — what the ``plantkg`` console script (engine.control.entry) runs for every command line it does not hand to a server — in a fresh
interpreter and reads the modules it ended with (``sys.modules``; ``-X importtime`` misses modules
loaded through ``importlib.import_module``, as the lazy command group does). No timing is asserted:
``benchmarks/bench_cli.py`` measures it.
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
from pathlib import Path

import click
import pytest

from engine.cli import BUILTIN_COMMANDS, PLUGIN_GROUP, LazyGroup, cli, main
from engine.cli.plugins import Plugin, find_plugins

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "ontology" / "examples" / "robot-cell.ttl"

#: Runs ``main(ARGS)``, then writes the exit code and the sorted module names to the file given first.
PROBE = (
    "import json, sys\n"
    "out = sys.argv.pop(1)\n"
    "from engine.cli import main\n"
    "code = main(sys.argv[1:])\n"
    "with open(out, 'w', encoding='utf-8') as f:\n"
    "    json.dump({'code': code, 'modules': sorted(sys.modules)}, f)\n"
)

#: What no command needs to start, list its help or make a plan.
NEVER_FOR_PLAN = ("engine.agent.server", "engine.agent.app", "engine.agent.manager", "engine.web",
                  "flask", "werkzeug", "jinja2", "rdflib.plugins.sparql", "pyshacl", "owlready2",
                  "confluent_kafka", "paho", "aiomqtt", "engine.apply", "engine.cli.progress")
#: What ``--help`` (and ``plan --help``) does not need either: no graph library at all.
NEVER_FOR_HELP = NEVER_FOR_PLAN + ("rdflib", "pyoxigraph", "engine.pipeline", "engine.agent",
                                   "engine.model", "kg.load", "kg.validate", "engine.cli.reconcile")


def _probe(tmp_path: Path, *args: str) -> tuple[int, list[str]]:
    out = tmp_path / "modules.json"
    proc = subprocess.run([sys.executable, "-c", PROBE, str(out), *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=120, check=False)
    assert out.exists(), f"the probe did not finish: {proc.stderr[-2000:]}"
    found = json.loads(out.read_text(encoding="utf-8"))
    return found["code"], found["modules"]


def _loaded(modules: list[str], prefixes: tuple[str, ...]) -> list[str]:
    return [m for m in modules if any(m == p or m.startswith(p + ".") for p in prefixes)]


@pytest.mark.parametrize("args", [["--help"], ["plan", "--help"], ["apply", "--help"], ["check", "--help"],
                                  ["--version"]],
                         ids=lambda a: " ".join(a))
def test_help_and_version_load_no_graph_library_and_no_server(tmp_path: Path, args: list[str]) -> None:
    code, modules = _probe(tmp_path, *args)
    assert code == 0
    assert _loaded(modules, NEVER_FOR_HELP) == []


def test_help_lists_every_command_and_loads_only_the_command_modules(tmp_path: Path) -> None:
    code, modules = _probe(tmp_path, "--help")
    assert code == 0
    for target in BUILTIN_COMMANDS.values():  # listing a command imports its (light) module
        assert target.partition(":")[0] in modules
    assert "fleet.cli" in modules  # the plugin is listed too (its group is light)
    assert "importlib.metadata" not in modules  # engine.cli.plugins reads entry_points.txt itself


def test_a_command_imports_only_its_own_module(tmp_path: Path) -> None:
    code, modules = _probe(tmp_path, "validate", "--help")
    assert code == 0
    command_modules = {t.partition(":")[0] for t in BUILTIN_COMMANDS.values()}
    assert sorted(command_modules & set(modules)) == ["engine.cli.validate"]
    assert "importlib.metadata" not in modules  # a built-in name: the plugins are not even looked up


def _agents_file_of_nobody(tmp_path: Path) -> Path:
    """An agents file whose agents do not answer (a port that was free a moment ago)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    token = tmp_path / "token"
    token.write_text("not-a-real-token\n", encoding="utf-8")
    token.chmod(0o600)
    agents = tmp_path / "agents.toml"
    agents.write_text("".join(f'[agents."{host}"]\nurl = "http://127.0.0.1:{port}"\n'
                              f'token_file = "{token}"\n' for host in ("127.0.0.2", "127.0.0.3")),
                      encoding="utf-8")
    return agents


def test_plan_runs_the_pipeline_without_the_agent_server_or_rdflib_sparql(tmp_path: Path) -> None:
    code, modules = _probe(tmp_path, "plan", str(EXAMPLE), "--agents", str(_agents_file_of_nobody(tmp_path)))
    assert code == 2  # made the plan, which cannot be applied: the agents did not answer
    assert {"kg.validate", "engine.derive", "engine.plan", "engine.agent.client"} <= set(modules)
    assert _loaded(modules, NEVER_FOR_PLAN) == []


def test_the_constants_written_out_for_cheap_listing_match_their_sources() -> None:
    from engine.agent.server import DEFAULT_PORT
    from engine.cli import agent, validate
    from kg.validate import ENGINES

    assert agent.DEFAULT_PORT == DEFAULT_PORT
    assert validate.ENGINES == ENGINES


def test_every_builtin_resolves_to_its_command() -> None:
    ctx = click.Context(cli)
    for name in BUILTIN_COMMANDS:
        command = cli.get_command(ctx, name)
        assert isinstance(command, click.Command) and command.name == name
    assert cli.get_command(ctx, "no-such-command") is None
    assert cli.list_commands(ctx) == sorted(cli.list_commands(ctx))


def test_plugins_are_found_as_importlib_metadata_finds_them() -> None:
    from importlib import metadata

    groups = {e.group for d in metadata.distributions() for e in d.entry_points}
    assert {PLUGIN_GROUP, "plantkg.drivers", "console_scripts"} <= groups
    for group in sorted(groups):
        expected = [(e.name, e.value) for e in metadata.entry_points(group=group)]
        assert [(p.name, p.value) for p in find_plugins(group)] == expected, group


def test_the_first_distribution_of_a_name_wins_and_other_groups_are_ignored(tmp_path: Path) -> None:
    for where, value in (("a", "first:command"), ("b", "second:command")):
        info = tmp_path / where / "some_pkg-1.0.dist-info"
        info.mkdir(parents=True)
        (info / "entry_points.txt").write_text(
            f"# comment\n[console_scripts]\nx = other:main\n\n[{PLUGIN_GROUP}]\nhi = {value}\n",
            encoding="utf-8")
    (tmp_path / "b" / "other-2.0.dist-info").mkdir()  # no entry_points.txt: nothing, no error
    paths = [str(tmp_path / "a"), str(tmp_path / "missing"), str(tmp_path / "b")]
    assert find_plugins(PLUGIN_GROUP, paths) == [Plugin("hi", "first:command", PLUGIN_GROUP)]


def test_a_plugin_loads_its_attribute_or_says_what_is_wrong() -> None:
    assert Plugin("p", "engine.cli:cli", PLUGIN_GROUP).load() is cli
    assert Plugin("p", "engine.cli.plugins:Plugin.load", PLUGIN_GROUP).load() is Plugin.load
    with pytest.raises(ValueError, match="is not 'module:attribute'"):
        Plugin("p", "not a value!", PLUGIN_GROUP).load()


@pytest.fixture
def group_with_plugins(monkeypatch: pytest.MonkeyPatch) -> LazyGroup:
    plugins = [Plugin("zz-broken", "no_such_module_xyz:command", PLUGIN_GROUP),
               Plugin("plan", "no_such_module_xyz:command", PLUGIN_GROUP),
               Plugin("hello", "tests.unit.test_cli_imports:hello_command", PLUGIN_GROUP),
               Plugin("hello", "no_such_module_xyz:command", PLUGIN_GROUP)]  # a second one: ignored
    monkeypatch.setattr("engine.cli.find_plugins", lambda group: [p for p in plugins if p.group == group])
    group = LazyGroup("plantkg", builtins={"plan": BUILTIN_COMMANDS["plan"]}, plugin_group=PLUGIN_GROUP)
    return group


@click.command("hello")
def hello_command() -> None:
    """Say hello (a plugin command of the tests)."""
    click.echo("hello from a plugin")


def test_plugins_are_loaded_when_used_and_never_shadow_a_builtin(group_with_plugins: LazyGroup,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    from engine.cli.common import run_guarded

    group = group_with_plugins
    assert group.list_commands(click.Context(group)) == ["hello", "plan", "zz-broken"]
    assert group.commands == {}  # listing names loads nothing
    assert run_guarded(group, ["hello"]) == 0
    assert capsys.readouterr().out == "hello from a plugin\n"
    assert group.get_command(click.Context(group), "plan").callback.__module__ == "engine.cli.plan"
    code = run_guarded(group, ["zz-broken"])
    err = capsys.readouterr().err
    assert code == 1
    assert "plugin command 'zz-broken' (no_such_module_xyz:command) cannot be loaded" in err
    assert "No module named 'no_such_module_xyz'" in err


def test_the_real_entry_point_still_gives_plantkg_fleet(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["fleet", "--help"]) == 0
    assert "AGV fleet" in capsys.readouterr().out
