"""plan / apply / destroy / status commands: output, confirmation and exit codes.

The plant is the real robot-cell example, loaded and validated for real; the agents are the
in-test double (tests/unit/fake_agents.py) and ``derive`` is replaced by the desired state of the
matching planning case, so these tests check the commands' logic only. The real pipeline and real
agents are exercised by tests/integration/test_apply_*.py.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import pytest

from engine import pipeline
from engine.cli import main
from engine.cli import reconcile
from engine.errors import PermanentDispatchError
from engine.model import DesiredState, ObservedState
from tests.unit.fake_agents import FakeFleet
from tests.unit.plan_data import load_case

ROOT = Path(__file__).resolve().parents[2]
PLANT = ROOT / "ontology" / "examples" / "robot-cell.ttl"


class Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.fixture
def fleet(monkeypatch: pytest.MonkeyPatch) -> FakeFleet:
    fleet = FakeFleet()
    desired, _, _ = load_case("empty-all-create")
    monkeypatch.setattr(reconcile.AgentDirectory, "load", classmethod(lambda cls, path=None: fleet.directory()))
    monkeypatch.setattr(pipeline, "derive_desired", lambda plant, result, engine="auto": desired)
    return fleet


def run(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def dispatched(fleet: FakeFleet) -> list[tuple[str, str]]:
    return [(v, k) for v, k in fleet.verbs() if v not in ("list_brokers", "list_bridges")]


def test_plan_shows_changes_and_detailed_exit_code(fleet: FakeFleet, capsys) -> None:  # type: ignore[no-untyped-def]
    code, out, _ = run(capsys, "plan", PLANT)
    assert code == 0 and "Plan: 6 to create, 0 to update, 0 to replace, 0 to destroy." in out
    assert run(capsys, "plan", PLANT, "--detailed-exitcode")[0] == 2  # changes pending, as Terraform
    code, out, _ = run(capsys, "plan", PLANT, "--format", "json")
    assert json.loads(out)["summary"]["create"] == 6
    assert dispatched(fleet) == []


def test_apply_with_yes_applies_and_reports(fleet: FakeFleet, capsys) -> None:  # type: ignore[no-untyped-def]
    code, out, err = run(capsys, "apply", PLANT, "--yes")
    assert code == 0, out + err
    assert "broker.kafka: Created after" in out
    assert "Apply complete: 6 changed, 0 failed, 0 skipped" in out
    code, out, _ = run(capsys, "plan", PLANT, "--detailed-exitcode")
    assert code == 0 and out.rstrip().endswith("No changes. The plant matches its description.")
    code, out, _ = run(capsys, "apply", PLANT)  # nothing to do: no question asked
    assert code == 0 and "No changes." in out


def test_apply_refuses_without_terminal_and_yes(fleet: FakeFleet, capsys) -> None:  # type: ignore[no-untyped-def]
    code, out, err = run(capsys, "apply", PLANT)
    assert code == 2
    assert "refusing to apply without confirmation" in err and "--yes" in err
    assert "Traceback" not in err and dispatched(fleet) == []


def test_apply_asks_on_a_terminal(fleet: FakeFleet, capsys, monkeypatch: pytest.MonkeyPatch) -> None:  # type: ignore[no-untyped-def]
    monkeypatch.setattr("sys.stdin", Terminal("no\n"))
    code, out, _ = run(capsys, "apply", PLANT)
    assert code == 130 and "Only 'yes' will be accepted" in out and dispatched(fleet) == []
    monkeypatch.setattr("sys.stdin", Terminal("yes\n"))
    code, out, _ = run(capsys, "apply", PLANT)
    assert code == 0 and "Apply complete" in out


def test_invalid_plant_dispatches_nothing(fleet: FakeFleet, capsys, tmp_path: Path,  # type: ignore[no-untyped-def]
                                          monkeypatch: pytest.MonkeyPatch) -> None:
    def no_agents(*_a, **_k):  # type: ignore[no-untyped-def]
        raise AssertionError("an agent was asked about an invalid plant")

    monkeypatch.setattr(pipeline, "observe_agents", no_agents)
    bad = tmp_path / "bad.ttl"
    bad.write_text(PLANT.read_text().replace('pk:port 9092', 'pk:port 0'))
    for command in ("apply", "plan", "destroy", "status"):
        code, out, err = run(capsys, command, bad, "--yes") if command in ("apply", "destroy") \
            else run(capsys, command, bad)
        assert code == 1, (command, out, err)
        assert "Violation" in out and "nothing was planned, started or stopped" in err
    assert fleet.calls == []


def test_unreachable_agent_makes_plan_and_apply_refuse(fleet: FakeFleet, capsys) -> None:  # type: ignore[no-untyped-def]
    fleet.down.add("127.0.0.3")
    code, out, _ = run(capsys, "plan", PLANT)
    assert code == 2 and "! 127.0.0.3" in out and "cannot be applied" in out
    code, out, err = run(capsys, "apply", PLANT, "--yes")
    assert code == 2 and "the agent of 127.0.0.3 did not answer" in err
    assert dispatched(fleet) == []


def test_failed_change_exits_3_and_names_it(fleet: FakeFleet, capsys) -> None:  # type: ignore[no-untyped-def]
    fleet.fail[("put_broker", "kafka")] = [PermanentDispatchError("422: kafka would not start",
                                                                  hint="see its log")]
    code, out, _ = run(capsys, "apply", PLANT, "--yes")
    assert code == 3
    assert "Apply finished with problems: 3 changed, 1 failed, 2 skipped" in out
    assert "✗ broker.kafka: 422: kafka would not start (see its log)" in out
    assert "Still to do: broker.kafka" in out
    code, out, _ = run(capsys, "apply", PLANT, "--yes")  # the re-run converges
    assert code == 0 and "Apply complete: 3 changed" in out


def test_status_table_and_destroy(fleet: FakeFleet, capsys) -> None:  # type: ignore[no-untyped-def]
    code, out, _ = run(capsys, "status", PLANT)
    assert code == 2  # not converged: nothing runs yet
    brokers, bridges = out.split("\n\n")
    assert [line.split()[3] for line in brokers.splitlines()[1:]] == ["absent", "absent"]
    assert bridges.splitlines()[1].split()[:3] == ["bridge.mosquitto.kafka", "mqtt-kafka", "absent"]
    run(capsys, "apply", PLANT, "--yes")
    code, out, _ = run(capsys, "status", PLANT)
    assert code == 0  # converged
    brokers, bridges = out.split("\n\n")
    header, *rows = brokers.splitlines()
    assert bridges.splitlines()[0].split() == ["BRIDGE", "MECHANISM", "STATUS", "ROUTES", "FORWARDED",
                                               "RATE/S", "RETRIED", "LAG", "ERROR"]
    assert bridges.splitlines()[1].split()[:8] == [
        "bridge.mosquitto.kafka", "mqtt-kafka", "running", "robot.abb-irb120.position", "out", "0", "0.0", "0"]
    assert header.split() == ["ID", "KIND", "HOST:PORT", "STATUS", "PID", "UPTIME", "RESTARTS", "TOPICS",
                              "ACCESS"]
    assert rows[0].split()[:4] == ["kafka", "kafka", "127.0.0.3:9092", "running"]
    assert rows[0].split()[-2:] == ["2/2", "open"]  # nobody in the robot cell has a pk:secretRef
    code, out, _ = run(capsys, "destroy", PLANT, "--yes")
    assert code == 0 and "Destroy complete: 6 changed" in out
    assert fleet.brokers == {}
    code, out, _ = run(capsys, "destroy", PLANT, "--yes")
    assert code == 0 and "Nothing to destroy" in out


def test_bad_agents_file_is_a_typed_error(capsys, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    code, _, err = run(capsys, "plan", PLANT, "--agents", tmp_path / "missing.toml")
    assert code == 2 and "no such agents file" in err and "Traceback" not in err


def test_desired_state_double_is_robot_cell() -> None:
    desired, _, _ = load_case("empty-all-create")
    assert isinstance(desired, DesiredState) and {b.id for b in desired.brokers} == {"kafka", "mosquitto"}


def test_live_progress_redraws_a_status_line() -> None:
    from engine.apply import ApplyEvent, EventKind
    from engine.cli.progress import Progress
    from engine.model import Action

    now = [100.0]
    out = Terminal()
    with Progress(out, live=True, clock=lambda: now[0]) as progress:
        progress(ApplyEvent(EventKind.START, "broker.kafka", Action.CREATE))
        now[0] += 12.0
        progress._draw_status()
        progress(ApplyEvent(EventKind.DONE, "broker.kafka", Action.CREATE, elapsed=12.3))
    text = out.getvalue()
    assert "running: broker.kafka 12s" in text
    assert "broker.kafka: Created after 12s" in text
    assert text.endswith("\r\x1b[2K") or "\x1b[2K" in text.splitlines()[-1]
    assert "Creating..." not in text  # in a terminal a start shows only in the status line


def test_plain_progress_prints_a_line_per_start_and_finish() -> None:
    from engine.apply import ApplyEvent, EventKind
    from engine.cli.progress import Progress
    from engine.model import Action

    out = io.StringIO()
    with Progress(out) as progress:
        progress(ApplyEvent(EventKind.START, "topic.k.t", Action.UPDATE))
        progress(ApplyEvent(EventKind.RETRY, "topic.k.t", Action.UPDATE, 1.0, 1, "503; retrying in 0.6 s"))
        progress(ApplyEvent(EventKind.DONE, "topic.k.t", Action.UPDATE, 1.7, 2))
    assert out.getvalue().splitlines() == [
        "topic.k.t: Updating...",
        "topic.k.t: attempt 1 failed: 503; retrying in 0.6 s",
        "topic.k.t: Updated after 1.7s (2 attempts)",
    ]


def test_detailed_exitcode_is_terraforms(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    """0 no changes (above), 2 changes pending (above), 1 any error — never 2 for an error."""
    broken = tmp_path / "broken.ttl"
    broken.write_text("this is not turtle", encoding="utf-8")
    code, _, err = run(capsys, "plan", str(broken), "--detailed-exitcode")
    assert code == 1 and "broken.ttl" in err
    assert run(capsys, "plan", str(broken))[0] == 2  # without the flag: unusable input, as before


def test_status_json_is_typed_and_says_whether_the_plant_converged(fleet: FakeFleet, capsys) -> None:  # type: ignore[no-untyped-def]
    code, out, _ = run(capsys, "status", PLANT, "--format", "json")
    answer = json.loads(out)
    assert code == 2 and answer["converged"] is False
    assert {b["status"] for b in answer["brokers"]} == {"absent"} and answer["brokers"][0]["pid"] is None
    run(capsys, "apply", PLANT, "--yes")
    code, out, _ = run(capsys, "status", PLANT, "--format", "json")
    answer = json.loads(out)
    assert code == 0 and answer["converged"] is True and answer["unreachable"] == []
    kafka = next(b for b in answer["brokers"] if b["id"] == "kafka")
    assert kafka["status"] == "running" and kafka["in_plant"] is True
    assert isinstance(kafka["restarts"], int) and (kafka["topics_present"], kafka["topics_wanted"]) == (2, 2)
    assert isinstance(answer["bridges"][0]["forwarded"], int)


def test_status_of_an_unreadable_plant_is_an_error(capsys, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    broken = tmp_path / "broken.ttl"
    broken.write_text("not turtle", encoding="utf-8")
    code, _, err = run(capsys, "status", str(broken))
    assert code == 1 and "broken.ttl" in err


def test_a_broker_whose_agent_did_not_answer_shows_unknown_topics_not_zero() -> None:
    from engine.cli.status import status_rows

    desired, _, _ = load_case("empty-all-create")
    host = desired.brokers[0].host
    rows = status_rows(desired, ObservedState(unreachable=(host,)), 0.0)
    row = next(r for r in rows if r["id"] == desired.brokers[0].id)
    wanted = len(desired.topics_of(desired.brokers[0].id))
    assert row["status"] == "unknown" and row["topics"] == f"?/{wanted}"  # not "0/N", which reads as missing
