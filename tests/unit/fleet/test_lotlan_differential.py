"""Differential test: fleet.lotlan against the LoTLan authors' own implementation.

Every program of tests/cases/lotlan (the authors' examples and tests, and ours) is given to
lotlan-scheduler 1.1.2 (PyPI; in the test extra with antlr4-python3-runtime==4.8 and
sqlalchemy<2, which install alongside the project's pins) in a SUBPROCESS whose working
directory is a temporary folder, because lotlan-scheduler writes files (Petri-net drawings, a
sqlite database) into the working directory and prints on stdout. Both must accept the same
programs and refuse the same programs, except the cases listed in DIFFERENCES, where we differ on
purpose; for those the test checks that the verdicts really differ, so the list cannot go stale.

Agreeing on a verdict is not agreeing on the reasons: lotlan-scheduler stops at the first syntax
error and often refuses a file for another reason than we do (tests/cases/lotlan/*/NAME.json has
our errors). A "crashed" verdict (an exception other than its ValueError) counts as refused.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

CASES = Path(__file__).resolve().parents[2] / "cases" / "lotlan"
RUNNER = Path(__file__).with_name("lotlan_scheduler_run.py")

_CYCLE = ("we refuse an OnDone cycle (a task chain that never finishes); the authors use it for "
          "endless processes, the fleet manager runs jobs that end (Repeat N for repetitions)")
_NO_TRANSPORT = ("we refuse a Task without Transport From/To: the task planner has nothing to assign; "
                 "lotlan-scheduler accepts it")
_WAIT_SELF = ("we refuse a task whose TriggeredBy waits for its own IsDone: it can never start "
              "(a deadlock lotlan-scheduler does not look for)")

# case (folder/name) -> why we decide differently from lotlan-scheduler 1.1.2
DIFFERENCES: dict[str, str] = {
    # stricter: we refuse, lotlan-scheduler accepts
    "authors/docs-infinite-loop": _CYCLE,
    "authors/scheduler-petrinet-generation-ondoneselfloop": _CYCLE,
    "authors/scheduler-scheduling-005-self-loop": _CYCLE,
    "authors/scheduler-scheduling-010-self-loop-trb-fb": _CYCLE,
    "authors/scheduler-tests-valid-hellotaskcomments": _CYCLE,
    "authors/scheduler-tests-valid-hellotaskrepeatforever": _CYCLE + "; " + _NO_TRANSPORT,
    "authors/scheduler-tests-valid-hellotasknewlinesbetweenstatements": _CYCLE + "; " + _NO_TRANSPORT,
    "authors/scheduler-tests-valid-hellotaskwithdot": _WAIT_SELF,
    "authors/scheduler-tests-valid-hellotaskconstraints": (
        "we check the names in Constraints (cost, emission are not defined); lotlan-scheduler "
        "does not look at Constraints at all"),
    "ours/ondone-cycle": _CYCLE,
    "ours/repeat-zero": "we refuse Repeat 0 ('forever' in the LoTLan docs): a job must finish",
    "ours/from-equals-to": ("we refuse From == To; lotlan-scheduler accepts it and then leaves the "
                            "delivery's location name empty"),
    "ours/task-without-transport": _NO_TRANSPORT,
    "ours/step-without-location": ("we refuse a TransportOrderStep without Location: there is "
                                   "nowhere to send the vehicle; lotlan-scheduler accepts it"),
    "ours/integer-event-in-condition": (
        "we refuse a non-Boolean event used as a condition anywhere; lotlan-scheduler checks that "
        "only when the event is the whole condition, not inside and/or"),
    "ours/bad-characters": ("we refuse a character that is no part of the language; "
                            "lotlan-scheduler's lexer drops it silently (its lexer errors are "
                            "switched off) and accepts the file"),
    "ours/end-followed-by-text": ("we refuse text after End; lotlan-scheduler's lexer drops it "
                                  "silently"),
    "ours/primitive-template-redefined": (
        "we refuse a Template Event without the primitive's attributes; lotlan-scheduler ignores "
        "the templates a program declares and always uses its built-in four"),
    "ours/repeated-settings": ("we refuse an attribute set twice, Parameters given twice and a "
                               "task state other than IsDone; lotlan-scheduler keeps the last "
                               "value and accepts any word after the dot"),
    "ours/constraint-in-condition": ("we refuse a Constraint in FinishedBy (it belongs in "
                                     "Constraints); lotlan-scheduler accepts it in a comparison"),
    "ours/number-in-condition": ("we refuse a number as a condition inside and/or; lotlan-scheduler "
                                 "refuses it only as the whole condition"),
    # more lenient: we accept, lotlan-scheduler refuses (its bugs, or for the fleet's data)
    "ours/parameters": ("three Parameters: lotlan-scheduler counts the values of From wrongly when "
                        "there are more than two (it nests them) and refuses a correct program"),
    "ours/parenthesised-condition": ("a whole condition in parentheses: lotlan-scheduler's check "
                                     "takes the '(' for an operand and refuses it"),
    "ours/isdone-in-condition": ("task.IsDone inside and/or: lotlan-scheduler accepts a task's "
                                 "state only as the whole condition"),
    "ours/header-whitespace": ("a tab between Task and its name: lotlan-scheduler's lexer wants "
                               "a space there"),
    "ours/transport-blank-line": ("a blank or comment line between Transport, From and To: "
                                  "lotlan-scheduler wants them on consecutive lines"),
    "ours/lenient-values": ('quoted values may hold any character but a quote, e.g. NGSI ids '
                            '"urn:ngsi-ld:Station:loading-1"; lotlan-scheduler allows only letters, '
                            "digits and _ (or digits, *, / and spaces)"),
}


@pytest.fixture(scope="module")
def scheduler_verdicts(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict]:
    try:
        import lotlan_scheduler  # noqa: F401
    except ImportError:
        pytest.fail("lotlan-scheduler is missing: install the test extra (pip install -e '.[test]')")
    workdir = tmp_path_factory.mktemp("lotlan-scheduler-cwd")
    programs = sorted(CASES.glob("*/*.tl"))
    done = subprocess.run([sys.executable, str(RUNNER), *map(str, programs)], cwd=workdir,
                          capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    verdicts = {}
    for line in done.stdout.splitlines():
        record = json.loads(line)
        path = Path(record["file"])
        verdicts[f"{path.parent.name}/{path.stem}"] = record
    assert len(verdicts) == len(programs)
    return verdicts


def _ours(case: str) -> bool:
    return json.loads((CASES / f"{case}.json").read_text(encoding="utf-8"))["accepted"]


CASE_NAMES = sorted(f"{p.parent.name}/{p.stem}" for p in CASES.glob("*/*.tl"))


@pytest.mark.parametrize("case", CASE_NAMES)
def test_same_verdict_as_the_authors_implementation(case: str, scheduler_verdicts: dict) -> None:
    theirs = scheduler_verdicts[case]
    they_accept = theirs["verdict"] == "accepted"
    we_accept = _ours(case)
    if case in DIFFERENCES:
        assert we_accept != they_accept, f"listed as a difference but both decide alike: {case}"
    else:
        assert we_accept == they_accept, (
            f"{case}: we {'accept' if we_accept else 'refuse'}, lotlan-scheduler "
            f"{theirs['verdict']}: {theirs['errors'][:2]}")


def test_every_listed_difference_is_a_case() -> None:
    assert set(DIFFERENCES) <= set(CASE_NAMES)


def test_the_expected_files_match_the_implementation() -> None:
    """The verdicts compared above come from the .json files; they must be what we really decide."""
    from fleet.lotlan import analyse

    for case in CASE_NAMES:
        text = (CASES / f"{case}.tl").read_text(encoding="utf-8")
        assert (analyse(text)[0] is not None) == _ours(case), case


def test_lotlan_scheduler_wrote_nothing_here(scheduler_verdicts: dict) -> None:
    for name in ("transport_order_logger.db",):
        assert not (Path.cwd() / name).exists()
    assert not list(CASES.rglob("*.dot"))
