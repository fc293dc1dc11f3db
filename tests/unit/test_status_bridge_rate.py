"""``plantkg status`` and a bridge whose forwarded rate runs away (issue 15): the ``rate/s`` column,
the typed JSON value, which bridges are above ``--max-bridge-rate`` and the exit code. Cases as data;
the end-to-end run with real brokers is tests/integration/test_status_bridge_rate.py."""

from __future__ import annotations

import json
from dataclasses import replace

import pytest

from engine import pipeline
from engine.cli import reconcile

from engine.cli.status import (
    BRIDGE_HEADERS,
    DEFAULT_MAX_BRIDGE_RATE,
    EXIT_CONVERGED,
    EXIT_NOT_CONVERGED,
    RunawayBridge,
    _typed_bridge,
    bridge_rows,
    runaway_bridges,
    show_rate,
    verdict,
)
from engine.model import (
    BridgeDirection,
    BridgeEnd,
    BridgeMechanism,
    BridgeRoute,
    BridgeSpec,
    BridgeStatus,
    DesiredState,
    ObservedBridge,
    ObservedState,
)
from tests.unit.fake_agents import FakeFleet
from tests.unit.plan_data import load_case
from tests.unit.test_apply_cli import PLANT, run


def spec(local: str, remote: str, mechanism: BridgeMechanism = BridgeMechanism.WORKER) -> BridgeSpec:
    kind = "mosquitto" if mechanism is BridgeMechanism.MOSQUITTO else "kafka"
    return BridgeSpec(BridgeEnd(local, "mosquitto", "127.0.0.1", 1883),
                      BridgeEnd(remote, kind, "127.0.0.1", 9092), mechanism,
                      (BridgeRoute("cell/temp", BridgeDirection.OUT),))


KAFKA = spec("mqtt1", "kafka1")
MOSQ = spec("mqtt1", "mqtt2", BridgeMechanism.MOSQUITTO)
STRAY = spec("mqtt9", "kafka9")  # a bridge an agent runs that the plant does not name


def seen(bridge: BridgeSpec, rate: float | None, forwarded: int | None = 10) -> ObservedBridge:
    return ObservedBridge(bridge, BridgeStatus.RUNNING, forwarded=forwarded, retried=0,
                          forwarded_per_s=rate)


SHOW_RATE_CASES = [(None, "-"), (0.0, "0.0"), (12.345, "12.3"), (36_000.0, "36000.0")]


@pytest.mark.parametrize(("value", "text"), SHOW_RATE_CASES)
def test_rate_cell(value: float | None, text: str) -> None:
    assert show_rate(value) == text


ROW_CASES = [
    # (name, desired bridges, observed bridges, expected {address: rate/s cell})
    ("worker bridge counts", (KAFKA,), (seen(KAFKA, 250.5),), {KAFKA.address: "250.5"}),
    ("Mosquitto's own bridge counts nothing", (MOSQ,), (seen(MOSQ, None, forwarded=None),), {MOSQ.address: "-"}),
    ("absent bridge", (KAFKA,), (), {KAFKA.address: "-"}),
    ("bridge not in the plant still shows its rate", (), (seen(STRAY, 7.0),), {STRAY.address: "7.0"}),
]


@pytest.mark.parametrize(("desired", "observed", "cells"), [c[1:] for c in ROW_CASES], ids=[c[0] for c in ROW_CASES])
def test_bridge_rows_have_a_rate_column(desired: tuple[BridgeSpec, ...], observed: tuple[ObservedBridge, ...],
                                        cells: dict[str, str]) -> None:
    rows = bridge_rows(DesiredState(bridges=desired), ObservedState(bridges=observed))
    assert {r["bridge"]: r["rate/s"] for r in rows} == cells
    assert all(set(BRIDGE_HEADERS) <= set(r) for r in rows)


@pytest.mark.parametrize(("observed", "expected"), [
    ((seen(KAFKA, 250.5),), 250.5),
    ((seen(MOSQ, None, forwarded=None),), None),
    ((), None),
])
def test_json_rate_is_a_number_or_null(observed: tuple[ObservedBridge, ...], expected: float | None) -> None:
    desired = DesiredState(bridges=tuple(b.spec for b in observed) or (KAFKA,))
    state = ObservedState(bridges=observed)
    [row] = [_typed_bridge(r, state) for r in bridge_rows(desired, state)]
    assert row["forwarded_per_s"] == expected and "rate/s" not in row


RUNAWAY_CASES = [
    # (name, observed bridges, limit, addresses above it)
    ("quiet plant", (seen(KAFKA, 5.0),), 50.0, []),
    ("exactly at the limit is not above it", (seen(KAFKA, 50.0),), 50.0, []),
    ("above the limit", (seen(KAFKA, 50.1),), 50.0, [KAFKA.address]),
    ("Mosquitto bridges are never judged", (seen(MOSQ, None, forwarded=None),), 0.001, []),
    ("a bridge outside the plant is judged too", (seen(KAFKA, 1.0), seen(STRAY, 40_000.0)),
     DEFAULT_MAX_BRIDGE_RATE, [STRAY.address]),
    ("the issue's loop at the default", (seen(KAFKA, 36_000.0 / 5),), DEFAULT_MAX_BRIDGE_RATE, []),
    ("every runaway is named", (seen(KAFKA, 300.0), seen(STRAY, 400.0)), 50.0, [KAFKA.address, STRAY.address]),
]


@pytest.mark.parametrize(("observed", "limit", "addresses"), [c[1:] for c in RUNAWAY_CASES],
                         ids=[c[0] for c in RUNAWAY_CASES])
def test_runaway_bridges(observed: tuple[ObservedBridge, ...], limit: float, addresses: list[str]) -> None:
    found = runaway_bridges(ObservedState(bridges=observed), limit)
    assert [r.address for r in found] == addresses
    assert all(r.limit == limit and r.rate > limit for r in found)


def test_the_warning_names_the_bridge_rate_limit_and_what_to_look_for() -> None:
    text = RunawayBridge("bridge.mqtt1.kafka1", 36_000.0, 10_000.0).warning
    for part in ("bridge.mqtt1.kafka1", "36,000.0", "10,000.0", "--max-bridge-rate", "loop", "publisher flooding"):
        assert part in text


VERDICT_CASES = [
    # (plan empty, agent unreachable, a bridge runs away, exit code)
    (True, False, False, EXIT_CONVERGED),
    (True, False, True, EXIT_NOT_CONVERGED),
    (False, False, False, EXIT_NOT_CONVERGED),
    (True, True, False, EXIT_NOT_CONVERGED),
    (False, True, True, EXIT_NOT_CONVERGED),
]


@pytest.mark.parametrize(("plan_empty", "unreachable", "runaway", "code"), VERDICT_CASES)
def test_verdict(plan_empty: bool, unreachable: bool, runaway: bool, code: int) -> None:
    assert verdict(plan_empty=plan_empty, unreachable=unreachable, runaway=runaway) == code


# --- the command, with the in-test agents (tests/unit/fake_agents.py) and a converged plant ---

@pytest.fixture
def fake(monkeypatch: pytest.MonkeyPatch) -> FakeFleet:
    fleet = FakeFleet()
    desired, _, _ = load_case("empty-all-create")
    monkeypatch.setattr(reconcile.AgentDirectory, "load", classmethod(lambda cls, path=None: fleet.directory()))
    monkeypatch.setattr(pipeline, "derive_desired", lambda plant, result, engine="auto": desired)
    return fleet


def test_status_command_exits_2_and_names_a_runaway_bridge(fake: FakeFleet,
                                                           capsys: pytest.CaptureFixture[str]) -> None:
    run(capsys, "apply", PLANT, "--yes")
    assert run(capsys, "status", PLANT)[0] == EXIT_CONVERGED
    [address] = fake.bridges
    fake.bridges[address] = replace(fake.bridges[address], forwarded_per_s=300.0)
    code, out, err = run(capsys, "status", PLANT)
    assert code == EXIT_CONVERGED and "300.0" in out and "warning" not in err  # below the default limit
    code, out, err = run(capsys, "status", PLANT, "--max-bridge-rate", "50")
    assert code == EXIT_NOT_CONVERGED
    assert f"bridge {address} forwards 300.0 messages/s, above the limit of 50.0" in err
    code, out, _ = run(capsys, "status", PLANT, "--max-bridge-rate", "50", "--format", "json")
    answer = json.loads(out)
    assert code == EXIT_NOT_CONVERGED and answer["converged"] is False and answer["max_bridge_rate"] == 50.0
    assert [r["bridge"] for r in answer["runaway_bridges"]] == [address]
    assert answer["bridges"][0]["forwarded_per_s"] == 300.0
    code, _, err = run(capsys, "status", PLANT, "--max-bridge-rate", "0")
    assert code == 2 and "--max-bridge-rate" in err  # a usage error, named
