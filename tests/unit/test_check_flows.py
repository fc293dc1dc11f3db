"""``plantkg check``'s pure parts: the flows of a plant (who publishes what, and every broker the
bridges' routes carry it to, chains followed) and the verdict on what arrived where.

Cases are tables: a plant written as brokers and bridge routes, a publication, and the expected
stops as ``broker@hops<-bridge sources``. One case runs the real pipeline on the robot cell.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from engine.check.flows import Flow, Publication, derive_flows, flow_of
from engine.check.verdict import Outcome, judge
from engine.model import (BridgeDirection, BridgeEnd, BridgeMechanism, BridgeRoute, BridgeSpec,
                          BrokerSpec, DesiredState)

ROOT = Path(__file__).resolve().parents[2]
T = "cell.position"
OUT, IN, BOTH = BridgeDirection.OUT, BridgeDirection.IN, BridgeDirection.BOTH
_MECH = {("mosquitto", "mosquitto"): BridgeMechanism.MOSQUITTO, ("mosquitto", "kafka"): BridgeMechanism.WORKER,
         ("mosquitto", "ngsi-v2"): BridgeMechanism.NGSI}


def plant(brokers: dict[str, str], bridges: list[tuple[str, str, list[tuple[str, BridgeDirection]]]]) -> DesiredState:
    """brokers: id -> kind; bridges: (local, remote, [(topic, direction)])."""
    specs = {b: BrokerSpec(b, f"urn:{b}", b, kind, "127.0.0.2", 1000 + i)
             for i, (b, kind) in enumerate(sorted(brokers.items()))}

    def end(b: str) -> BridgeEnd:
        return BridgeEnd(b, specs[b].kind, specs[b].host, specs[b].port)

    return DesiredState(brokers=tuple(specs.values()), bridges=tuple(
        BridgeSpec(end(l), end(r), _MECH[(specs[l].kind, specs[r].kind)],
                   tuple(BridgeRoute(t, d) for t, d in sorted(routes)))
        for l, r, routes in bridges))


def stops(flow: Flow | None) -> list[str]:
    assert flow is not None
    return [f"{s.broker}@{s.hops}" + ("<-" + "+".join(link.source for link in s.via) if s.via else "")
            for s in flow.stops]


M, K, C = "mosquitto", "kafka", "ngsi-v2"
FLOW_CASES = [
    # id, brokers, bridges, publishing broker, expected stops
    ("alone", {"a": M}, [], "a", ["a@0"]),
    ("mqtt-to-kafka", {"a": M, "k": K}, [("a", "k", [(T, OUT)])], "a", ["a@0", "k@1<-a"]),
    ("kafka-to-mqtt is IN at the mqtt end", {"a": M, "k": K}, [("a", "k", [(T, IN)])], "k", ["k@0", "a@1<-k"]),
    ("IN route does not carry from the local end", {"a": M, "k": K}, [("a", "k", [(T, IN)])], "a", ["a@0"]),
    ("another topic's route is not followed", {"a": M, "k": K}, [("a", "k", [("other", OUT)])], "a", ["a@0"]),
    ("both ways, from either end", {"a": M, "b": M}, [("a", "b", [(T, BOTH)])], "b", ["b@0", "a@1<-b"]),
    ("chain a->b->k", {"a": M, "b": M, "k": K},
     [("a", "b", [(T, OUT)]), ("b", "k", [(T, OUT)])], "a", ["a@0", "b@1<-a", "k@2<-b"]),
    ("fan out", {"a": M, "b": M, "c": M},
     [("a", "b", [(T, OUT)]), ("a", "c", [(T, OUT)])], "a", ["a@0", "b@1<-a", "c@1<-a"]),
    ("diamond: k fed by two bridges", {"a": M, "b": M, "c": M, "k": K},
     [("a", "b", [(T, OUT)]), ("a", "c", [(T, OUT)]), ("b", "k", [(T, OUT)]), ("c", "k", [(T, OUT)])],
     "a", ["a@0", "b@1<-a", "c@1<-a", "k@2<-b+c"]),
    ("a loop back to the source is not a stop", {"a": M, "b": M},
     [("a", "b", [(T, OUT)]), ("b", "a", [(T, OUT)])], "a", ["a@0", "b@1<-a"]),
    ("context broker is a stop (not watchable)", {"a": M, "ctx": C}, [("a", "ctx", [(T, OUT)])], "a",
     ["a@0", "ctx@1<-a"]),
]


@pytest.mark.parametrize(("brokers", "bridges", "source", "expected"),
                         [c[1:] for c in FLOW_CASES], ids=[c[0] for c in FLOW_CASES])
def test_flow_reaches_every_broker_the_routes_carry_it_to(brokers, bridges, source, expected) -> None:  # type: ignore[no-untyped-def]
    flow = flow_of(plant(brokers, bridges), Publication("r", "Robot", T, source))
    assert stops(flow) == expected


def test_watchable_kinds_and_unknown_broker() -> None:
    desired = plant({"a": M, "ctx": C}, [("a", "ctx", [(T, OUT)])])
    flow = flow_of(desired, Publication("r", "Robot", T, "a"))
    assert flow is not None and [s.watchable for s in flow.stops] == [True, False]
    assert flow.stops[1].via[0].bridge == "bridge.a.ctx" and flow.stops[1].via[0].mechanism == "mqtt-ngsi"
    assert flow_of(desired, Publication("r", "Robot", T, "nowhere")) is None


def test_derive_flows_sorts_and_merges_duplicates() -> None:
    desired = plant({"a": M, "k": K}, [("a", "k", [(T, OUT)])])
    pubs = [Publication("z", "Z", T, "a"), Publication("b", "B", "energy", "k"), Publication("z", "Z", T, "a")]
    flows = derive_flows(desired, pubs)
    assert [(f.resource_id, f.topic, stops(f)) for f in flows] == [
        ("b", "energy", ["k@0"]), ("z", T, ["a@0", "k@1<-a"])]


def test_robot_cell_flows_from_the_graph() -> None:
    from engine.check.publications import publications
    from engine.pipeline import run_pipeline

    result = run_pipeline([ROOT / "ontology" / "examples" / "robot-cell.ttl"], None, observe=False)
    assert result.desired is not None and result.plant is not None
    flows = derive_flows(result.desired, publications(result.plant))
    assert [(f.resource, f.topic, stops(f)) for f in flows] == [
        ("Raspberry Pi", "robot.abb-irb120.energy", ["kafka@0"]),
        ("ROS machine", "robot.abb-irb120.position", ["mosquitto@0", "kafka@1<-mosquitto"])]
    assert flows[1].stops[1].via[0].bridge == "bridge.mosquitto.kafka"


# --------------------------------------------------------------------------------- the verdict

CHAIN = plant({"a": M, "b": M, "k": K, "ctx": C},
              [("a", "b", [(T, OUT)]), ("b", "k", [(T, OUT)]), ("a", "ctx", [(T, OUT)])])
DIAMOND = plant({"a": M, "b": M, "c": M, "k": K},
                [("a", "b", [(T, OUT)]), ("a", "c", [(T, OUT)]), ("b", "k", [(T, OUT)]), ("c", "k", [(T, OUT)])])

VERDICT_CASES = [
    # id, plant, arrived, probe id, outcome, words the message must hold
    ("all arrived", CHAIN, {"a": 5, "b": 5, "k": 4}, None, Outcome.PASS, ["Robot (r)", "arrived at a, b, k"]),
    ("nothing at the source", CHAIN, {}, None, Outcome.NO_TRAFFIC,
     ["no traffic from Robot (r) on cell.position at a within 10 s"]),
    ("last hop missing", CHAIN, {"a": 5, "b": 5}, None, Outcome.FAIL,
     ["nothing arrived at k", "bridge bridge.b.k from b (mqtt-kafka, running)"]),
    ("first hop missing names both brokers", CHAIN, {"a": 5}, None, Outcome.FAIL,
     ["nothing arrived at b", "nothing arrived at k", "bridge.a.b"]),
    ("probe missing at the source", CHAIN, {}, "p1", Outcome.FAIL, ["the probe", "did not arrive there"]),
    ("probe everywhere", CHAIN, {"a": 1, "b": 1, "k": 1}, "p1", Outcome.PASS, ["the probe arrived at a, b, k"]),
]


@pytest.mark.parametrize(("desired", "arrived", "probe_id", "outcome", "words"),
                         [c[1:] for c in VERDICT_CASES], ids=[c[0] for c in VERDICT_CASES])
def test_verdict(desired, arrived, probe_id, outcome, words) -> None:  # type: ignore[no-untyped-def]
    flow = flow_of(desired, Publication("r", "Robot", T, "a"))
    assert flow is not None
    result = judge(flow, arrived, probe_id=probe_id, deadline=10.0,
                   bridge_status={"bridge.b.k": "running"})
    assert result.outcome is outcome
    for word in words:
        assert word in result.message
    assert not result.warnings
    ctx = [s for s in result.stops if s.stop.broker == "ctx"]
    assert ctx[0].arrived is None and "not checked" in ctx[0].note  # never passed, never failed


def test_a_probe_delivered_twice_through_two_paths_is_a_warning() -> None:
    flow = flow_of(DIAMOND, Publication("r", "Robot", T, "a"))
    assert flow is not None
    result = judge(flow, {"a": 1, "b": 1, "c": 1, "k": 2}, probe_id="p", deadline=5)
    assert result.outcome is Outcome.PASS
    assert len(result.warnings) == 1
    assert "arrived 2 times at k" in result.warnings[0] and "two bridge paths" in result.warnings[0]
    assert "bridge.b.k" in result.warnings[0] and "bridge.c.k" in result.warnings[0]
    passive = judge(flow, {"a": 3, "b": 3, "c": 3, "k": 6}, probe_id=None, deadline=5)
    assert passive.outcome is Outcome.PASS and not passive.warnings  # passive counts cannot tell


def test_a_flow_from_a_context_broker_is_not_checked() -> None:
    desired = plant({"a": M, "ctx": C}, [("a", "ctx", [(T, IN)])])
    flow = flow_of(desired, Publication("planner", "Planner", T, "ctx"))
    assert flow is not None
    result = judge(flow, {"a": 3}, probe_id=None, deadline=5)
    assert result.outcome is Outcome.NOT_CHECKED and not result.outcome.failed
    assert "ctx is a ngsi-v2 broker" in result.message


def test_reports_text_and_typed_json() -> None:
    from engine.check.report import render_json, render_text
    from engine.check.run import CheckResult

    flow = flow_of(CHAIN, Publication("r", "Robot", T, "a"))
    assert flow is not None
    failed = judge(flow, {"a": 5, "b": 5}, probe_id=None, deadline=10.0)
    check = CheckResult((failed,), probe=False, deadline=10.0, elapsed=10.01234)
    assert not check.passed
    doc = json.loads(render_json(check))
    assert doc["passed"] is False and doc["mode"] == "passive" and doc["elapsed_s"] == 10.012
    assert doc["counts"] == {"pass": 0, "fail": 1, "no-traffic": 0, "not-checked": 0}
    brokers = {b["broker"]: b for b in doc["flows"][0]["brokers"]}
    assert brokers["a"]["arrived"] == 5 and brokers["k"]["arrived"] == 0 and brokers["k"]["hops"] == 2
    assert brokers["ctx"]["arrived"] is None and brokers["ctx"]["checked"] is False
    assert isinstance(brokers["a"]["port"], int)
    assert brokers["k"]["via"] == [{"bridge": "bridge.b.k", "from": "b", "mechanism": "mqtt-kafka"}]
    text = render_text(check)
    assert text.splitlines()[0].startswith("FAIL Robot (r) on cell.position: 5 message(s) reached a")
    assert "1 flow(s), passive, deadline 10 s: 0 passed, 1 failed, 0 not checked" in text
    assert "not checked: ctx is a ngsi-v2 broker" in text


# ------------------------------------------------------------------- bad input: exit 2, no traceback

BAD_INPUT = [
    ("missing file", ["/nonexistent/plant.ttl"], "no such file"),
    ("deadline not positive", ["{plant}", "--deadline", "0"], "--deadline"),
    ("unknown format", ["{plant}", "--format", "yaml"], "--format"),
    ("missing agents file", ["{plant}", "--agents", "{tmp}/none.toml"], "no such agents file"),
    ("invalid plant", ["{invalid}"], "the plant has violations"),
]


@pytest.mark.parametrize(("args", "words"), [c[1:] for c in BAD_INPUT], ids=[c[0] for c in BAD_INPUT])
def test_bad_input_exits_2_with_a_message(args: list[str], words: str, tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    from engine.cli import main

    invalid = tmp_path / "invalid.ttl"
    invalid.write_text('@prefix pk: <https://w3id.org/plantkg/ontology#> .\n'
                       '<urn:b> a pk:Broker ; pk:id "b" ; pk:brokerType "mosquitto" .\n', encoding="utf-8")
    plant = ROOT / "ontology" / "examples" / "robot-cell.ttl"
    code = main(["check", *(a.format(plant=plant, tmp=tmp_path, invalid=invalid) for a in args)])
    out = capsys.readouterr()
    assert code == 2
    assert words in out.out + out.err and "Traceback" not in out.out + out.err
