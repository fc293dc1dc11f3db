"""fleet.lotlan's API and model: what the task planner gets, and how problems reach the user."""

from __future__ import annotations

import random
from pathlib import Path

import pytest

import fleet.lotlan as lotlan
from fleet.lotlan import cycles
from fleet.lotlan.errors import LotlanError
from fleet.lotlan.model import And, Compare, Const, Not, Or, Pos, Ref, RefKind, TaskAttribute
from fleet.lotlan.render import expression_text

CASES = Path(__file__).resolve().parents[2] / "cases" / "lotlan"

HEAD = '''Location a
    name = "loading_1"
    type = "Pallet"
End

Location b
    name = "unloading_1"
    type = "Pallet"
End

Event button
    name = "hmi_button"
    type = "Boolean"
End

Event level
    name = "fill_level"
    type = "Integer"
End

Time morning
    timing = "30 8 * * *"
End

TransportOrderStep atA
    Location a
    Parameters height, side
End

TransportOrderStep atB
    Location b
    FinishedBy button
End
'''


def task(body: str, name: str = "move") -> str:
    return f"\nTask {name}\n    Transport\n    From atA 5, \"left\"\n    To atB\n{body}End\n"


def test_a_program_resolves_steps_locations_and_arguments() -> None:
    program = lotlan.parse(HEAD + task("    Repeat 3\n"), "jobs.tl")
    move = program.task("move")
    assert move.pickup.step.location.physical_name == "loading_1"
    assert move.delivery.step.location.name == "b"
    assert move.pickup.bound_parameters == (("height", 5), ("side", "left"))
    assert move.repeat == 3 and move.on_done == () and move.triggered_by is None
    assert move.delivery.step.finished_by == Ref("button", Pos(32, 16), RefKind.EVENT)
    assert move.at == Pos(35, 6)
    assert [loc.name for loc in program.locations] == ["a", "b"]
    assert [t.name for t in program.times] == ["morning"] and program.file == "jobs.tl"
    with pytest.raises(KeyError):
        program.task("nothing")


def test_expression_tree_follows_the_authors_precedence() -> None:
    program = lotlan.parse(HEAD + task("    TriggeredBy !button == True or level > 2 and morning\n"))
    tree = program.task("move").triggered_by
    assert isinstance(tree, Or)
    assert isinstance(tree.left, Compare) and tree.left.op == "=="
    assert isinstance(tree.left.left, Not) and tree.left.right == Const(True, Pos(39, 28))
    assert isinstance(tree.right, And) and isinstance(tree.right.left, Compare)
    assert tree.right.right == Ref("morning", Pos(39, 50), RefKind.TIME)
    assert expression_text(tree) == "(!button == True) or ((level > 2) and morning)"


def test_task_state_and_literals_in_conditions() -> None:
    text = HEAD + task("") + task("    TriggeredBy move.IsDone and (false or level == 2.5)\n", "after")
    tree = lotlan.parse(text).task("after").triggered_by
    assert tree.left == TaskAttribute("move", "IsDone", Pos(45, 17))
    assert tree.right.left == Const(False, Pos(45, 34))
    assert tree.right.right.right == Const(2.5, Pos(45, 52))


def test_start_tasks_are_those_no_on_done_starts() -> None:
    text = HEAD + task("    OnDone second, third\n", "first") + task("", "second") + task("", "third")
    program = lotlan.parse(text)
    assert [t.name for t in program.start_tasks()] == ["first"]


def test_parse_raises_with_every_problem_and_a_hint() -> None:
    text = HEAD + task("    OnDone nobody\n    TriggeredBy ghost\n", "Move")
    with pytest.raises(LotlanError) as raised:
        lotlan.parse(text, "jobs.tl")
    error = raised.value
    assert [(d.line, d.column) for d in error.diagnostics] == [(35, 6), (39, 12), (40, 17)]
    lines = str(error).splitlines()
    assert lines[0].startswith("jobs.tl:35:6: task names start with a lowercase letter")
    assert lines[1].startswith("jobs.tl:39:12: OnDone names an unknown task 'nobody'")
    assert lines[2].startswith("jobs.tl:40:17: unknown name 'ghost' in TriggeredBy")
    assert "nothing of the program was used" in lines[-1]
    assert error.exit_code == 1


def test_windows_line_ends_parse_like_unix_ones() -> None:
    text = HEAD + task("    Repeat 2\n")
    assert lotlan.parse(text.replace("\n", "\r\n")) == lotlan.parse(text)


def test_a_file_without_a_final_newline_parses() -> None:
    assert lotlan.parse((HEAD + task("")).rstrip("\n")).task("move").repeat == 1


def test_blocks_parsed_one_by_one_give_the_same_program_as_the_whole_file() -> None:
    """The recovery path (a broken block elsewhere) keeps the good blocks as they are."""
    good = HEAD + task("    TriggeredBy button or level > 3\n")
    broken = good + "\nTask broken\n    Transport\n    From\nEnd\n"
    diagnostics = lotlan.check_text(broken)
    assert [(d.line, d.column) for d in diagnostics] == [(44, 9)]
    from fleet.lotlan import syntax

    assert syntax.parse_text(broken, "f").decls == syntax.parse_text(good, "f").decls


def test_load_reads_a_file_and_names_it_in_errors(tmp_path: Path) -> None:
    path = tmp_path / "jobs.tl"
    path.write_text(HEAD + task(""), encoding="utf-8")
    assert lotlan.load(path).file == str(path)
    with pytest.raises(LotlanError) as raised:
        lotlan.load(tmp_path / "missing.tl")
    assert raised.value.diagnostics[0].message.startswith("cannot read the file")


def test_the_paper_workflow_case_is_a_chain_of_two_transports() -> None:
    program = lotlan.load(CASES / "ours" / "paper-load-unload.tl")
    deliver, back = program.tasks
    assert (deliver.pickup.step.location.name, deliver.delivery.step.location.name) == (
        "loadingStation", "unloadingStation")
    assert deliver.on_done == ("returnToWait",) and back.delivery.step.location.name == "waitingArea"
    assert expression_text(deliver.pickup.step.finished_by) == "loaded == True"


def test_required_tasks_are_judged_conservatively() -> None:
    at = Pos(1, 1)
    done = {n: TaskAttribute(n, "IsDone", at) for n in "abc"}
    assert cycles.required_tasks(And(done["a"], done["b"], at)) == {"a", "b"}
    assert cycles.required_tasks(Or(done["a"], done["b"], at)) == frozenset()
    assert cycles.required_tasks(Or(And(done["a"], done["b"], at), done["a"], at)) == {"a"}
    assert cycles.required_tasks(Not(done["a"], at)) == frozenset()
    assert cycles.required_tasks(None) == frozenset()


def test_a_long_on_done_cycle_is_reported_once_with_its_chain() -> None:
    names = ["t0", "t1", "t2", "t3"]
    text = HEAD + "".join(task(f"    OnDone {names[(i + 1) % 4]}\n", n) for i, n in enumerate(names))
    diagnostics = lotlan.check_text(text)
    assert len(diagnostics) == 1
    assert "t0 -> t1 -> t2 -> t3 -> t0" in diagnostics[0].message


def test_mangled_programs_give_diagnostics_never_exceptions() -> None:
    """Seeded mutations of every case file: bad input is reported, never raised."""
    rng = random.Random(20261124)
    files = sorted(CASES.glob("*/*.tl"))
    pieces = list("aZ09_ \t\n#\"=.,()!<>-$") + ["End", "Task ", "From ", "\n    ", "OnDone x", "Repeat"]
    refused = 0
    for _ in range(600):
        text = rng.choice(files).read_text(encoding="utf-8")
        for _ in range(rng.randint(1, 3)):
            at = rng.randint(0, len(text))
            if rng.random() < 0.5:
                text = text[:at] + rng.choice(pieces) + text[at:]
            else:
                text = text[:at] + text[at + rng.randint(1, 20):]
        program, diagnostics = lotlan.analyse(text, "mangled.tl")
        assert (program is None) == bool(diagnostics)
        lines = text.count("\n") + 1
        assert all(1 <= d.line <= lines and d.column >= 1 for d in diagnostics), diagnostics
        refused += program is None
    assert refused > 300  # the mutations do break programs
