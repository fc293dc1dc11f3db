"""``plantkg explain``: the reasons come from the fast reasoner's own rules, on the robot cell.

The robot cell's bridge Mosquitto -> Kafka is required twice over: the plant asserts
``pk:bridgesTo``, and R1 fires (the ROS machine publishes the position on Mosquitto, the historian
subscribes to it on Kafka). Copies of the plant with the historian deleted (and the assertion kept
or dropped) show each reason alone, and "not required" when neither is left.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from engine.reasoning import rules_fast
from engine.reasoning.explain import MAX_REASONS, AddressError, explain, parse_address
from engine.reasoning.reason import INFERRED, input_graphs
from engine.reasoning.rules_tbox import dataset_options, read_tbox
from kg.load import load_plant
from kg.namespaces import PK

ROOT = Path(__file__).resolve().parents[2]
ROBOT_CELL = ROOT / "ontology" / "examples" / "robot-cell.ttl"
BRIDGE = "bridge.mosquitto.kafka"
R1 = "R1 publisher and subscriber on different brokers require a bridge"


def _variant(tmp_path: Path, *, historian: bool = True, bridges_to: bool = True) -> Path:
    """A copy of the robot cell, with the historian (the only subscriber on Kafka of the position)
    and/or Mosquitto's ``pk:bridgesTo`` assertion deleted."""
    text = ROBOT_CELL.read_text(encoding="utf-8")
    if not historian:
        text, n = re.subn(r"\nrc:historian\n(?:    .*\n)+", "\n", text)
        assert n == 1 and "rc:historian" not in text
    if not bridges_to:
        old = "    pk:hasTopic rc:robot-position ;\n    pk:bridgesTo rc:kafka .\n"
        assert old in text
        text = text.replace(old, "    pk:hasTopic rc:robot-position .\n")
    out = tmp_path / "robot-cell.ttl"
    out.write_text(text, encoding="utf-8")
    return out


def _explain(path: Path, address: str):  # noqa: ANN202
    result, explanation = explain([path], address)
    assert result.valid and explanation is not None, result.report
    return explanation


def test_bridge_names_r1_and_the_two_resources() -> None:
    e = _explain(ROBOT_CELL, BRIDGE)
    assert e.required and e.kind == "bridge"
    r1 = [r for r in e.reasons if r.rule == R1]
    assert len(r1) == 1  # one topic (the position) makes R1 fire from Mosquitto to Kafka
    premises = {(p.subject, p.predicate, p.object) for p in r1[0].premises}
    assert ("ROS machine (ros-machine)", "pk:publishes", "robot.abb-irb120.position (robot-position)") in premises
    assert ("ROS machine (ros-machine)", "pk:sendsTo", "mosquitto-cell (mosquitto)") in premises
    assert ("Historian database (historian)", "pk:subscribes",
            "robot.abb-irb120.position (robot-position)") in premises
    assert ("Historian database (historian)", "pk:sendsTo", "kafka-aggregation (kafka)") in premises
    assert all(p.source == "ontology/examples/robot-cell.ttl" or p.source == str(ROBOT_CELL)
               for p in r1[0].premises)  # every fact R1 read is asserted in the plant file
    c = r1[0].conclusion
    assert (c.subject, c.predicate, c.object) == ("mosquitto-cell (mosquitto)", "pk:requiresBridge",
                                                  "kafka-aggregation (kafka)")
    text = e.text()
    assert text.startswith(f"{BRIDGE} is required:")
    assert R1 in text and "ROS machine" in text and "Historian database" in text


def test_asserted_bridge_is_explained_with_its_file(tmp_path: Path) -> None:
    path = _variant(tmp_path, historian=False)
    e = _explain(path, BRIDGE)
    assert e.required
    assert [r.rule for r in e.reasons] == ["sub-properties: pk:bridgesTo ⊑ pk:requiresBridge"]
    (premise,) = e.reasons[0].premises
    assert (premise.subject, premise.predicate, premise.object, premise.source) == (
        "mosquitto-cell (mosquitto)", "pk:bridgesTo", "kafka-aggregation (kafka)", str(path))


def test_bridge_not_required_once_the_subscriber_is_gone(tmp_path: Path) -> None:
    before = _explain(_variant(tmp_path, bridges_to=False), BRIDGE)
    assert before.required and [r.rule for r in before.reasons] == [R1]  # R1 alone keeps it
    (tmp_path / "b").mkdir()
    after = _explain(_variant(tmp_path / "b", historian=False, bridges_to=False), BRIDGE)
    assert not after.required and after.reasons == ()
    assert "no rule concludes pk:requiresBridge between mosquitto and kafka" in after.text()
    assert after.text().startswith(f"{BRIDGE} is not required:")


def test_broker_is_explained_by_the_definition_of_deployed_broker() -> None:
    e = _explain(ROBOT_CELL, "broker.mosquitto")
    assert e.required and e.reasons
    assert {r.rule for r in e.reasons} == {"definition of pk:DeployedBroker"}
    assert all((r.conclusion.predicate, r.conclusion.object) == ("a", "pk:DeployedBroker") for r in e.reasons)
    # One reason is the ROS machine sending to it (the first branch of the definition).
    assert any(("ROS machine (ros-machine)", "pk:sendsTo", "mosquitto-cell (mosquitto)")
               in {(p.subject, p.predicate, p.object) for p in r.premises} for r in e.reasons)


def test_topic_is_explained_by_r2b_and_the_asserted_has_topic() -> None:
    e = _explain(ROBOT_CELL, "topic.kafka.robot.abb-irb120.energy")
    assert e.required
    rules = {r.rule for r in e.reasons}
    assert rules == {"sub-properties: pk:hasTopic ⊑ pk:mustCarry",
                     "R2a a publisher's broker must carry the published topic",
                     "R2b a subscriber's broker must carry the subscribed topic"}
    r2a = next(r for r in e.reasons if r.rule.startswith("R2a"))
    assert ("Raspberry Pi (raspberry-pi)", "pk:publishes", "robot.abb-irb120.energy (robot-energy)") in {
        (p.subject, p.predicate, p.object) for p in r2a.premises}


@pytest.mark.parametrize(("address", "why"), [
    ("broker.nope", "no broker has pk:id 'nope'"),
    ("topic.mosquitto.robot.abb-irb120.energy", "no topic named 'robot.abb-irb120.energy' must be carried"),
    ("bridge.kafka.mosquitto", "this pair's bridge is bridge.mosquitto.kafka"),
])
def test_addresses_not_required_say_why(address: str, why: str) -> None:
    e = _explain(ROBOT_CELL, address)
    assert not e.required and why in e.note


@pytest.mark.parametrize("address", ["bridge.mosquitto", "broker.", "topic.kafka", "topic.kafka.", "bridge..x",
                                     "queue.x", "broker.a b", ""])
def test_malformed_addresses_are_refused(address: str) -> None:
    with pytest.raises(AddressError, match="is not a plan address"):
        parse_address(address)


def _rule_labels() -> set[str]:
    """The labels of the SWRL rules in ontology/plantkg-rules.ttl and plantkg-access.ttl (A1, A2:
    the robot cell's publishers and subscribers get their rights), read from the files themselves."""
    import pyoxigraph as ox  # noqa: PLC0415

    store = ox.Store()
    for name in ("plantkg-rules.ttl", "plantkg-access.ttl"):
        store.load(path=str(ROOT / "ontology" / name), format=ox.RdfFormat.TURTLE)
    rows = store.query("PREFIX swrl: <http://www.w3.org/2003/11/swrl#> "
                       "PREFIX rdfs: <http://www.w3.org/2000/01/rdf-schema#> "
                       "SELECT ?l WHERE { ?r a swrl:Imp ; rdfs:label ?l }")
    return {row["l"].value for row in rows}


def test_ids_with_dots_split_where_the_plant_has_brokers(tmp_path: Path) -> None:
    text = ROBOT_CELL.read_text(encoding="utf-8").replace('pk:id "mosquitto"', 'pk:id "cell.mosquitto"')
    path = tmp_path / "robot-cell.ttl"
    path.write_text(text, encoding="utf-8")
    e = _explain(path, "bridge.cell.mosquitto.kafka")
    assert e.required and R1 in {r.rule for r in e.reasons}
    topic = _explain(path, "topic.cell.mosquitto.robot.abb-irb120.position")
    assert topic.required and topic.reasons
    assert _explain(path, "broker.cell.mosquitto").required


@pytest.mark.parametrize("asserted", [True, False], ids=["as-shipped", "no-hasTopic-no-bridgesTo"])
def test_every_fact_the_fast_engine_adds_has_its_rule(tmp_path: Path, asserted: bool) -> None:
    path = ROBOT_CELL
    if not asserted:  # nothing asserted that the rules would conclude: R1, R2a, R2b derive it all
        text = ROBOT_CELL.read_text(encoding="utf-8")
        text = text.replace("    pk:port 1883 ;\n    pk:hasTopic rc:robot-position ;\n    pk:bridgesTo rc:kafka .\n",
                            "    pk:port 1883 .\n")
        text = text.replace("    pk:port 9092 ;\n    pk:hasTopic rc:robot-position , rc:robot-energy .\n",
                            "    pk:port 9092 .\n")
        assert "pk:hasTopic" not in text and "pk:bridgesTo" not in text
        path = tmp_path / "robot-cell.ttl"
        path.write_text(text, encoding="utf-8")
    plant = load_plant([path])
    inputs = input_graphs(plant)
    program = rules_fast.compile_tbox(read_tbox(plant.store, inputs, str))
    outcome = rules_fast.run(program, plant.store, inputs, INFERRED, str)
    assert outcome.added
    assert set(outcome.provenance) == {(q.subject, q.predicate, q.object) for q in outcome.added}
    assert set(outcome.provenance.values()) <= {r.name for r in program.rules}
    swrl = {n[len("SWRL rule '"):-1] for n in outcome.provenance.values() if n.startswith("SWRL rule")}
    assert swrl <= _rule_labels()
    requires = {v for (_, p, _), v in outcome.provenance.items() if p.value == f"{PK}requiresBridge"}
    if asserted:
        # Every bridge and topic is asserted: the sub-properties derive them first, no SWRL rule
        # adds a fact — which is why explain lists every derivation, not the first one. (The
        # access rules A1, A2 still conclude each publisher's and subscriber's rights.)
        assert {label.split()[0] for label in swrl} == {"A1", "A2"} and requires == {"sub-properties"}
    else:
        assert {label.split()[0] for label in swrl} == {"R1", "R2a", "R2b", "A1", "A2"}
        assert requires == {f"SWRL rule '{R1}'"}
    # The recorded rule concludes its fact again through its own body (what explain asks it).
    by_name: dict[str, list[rules_fast.FastRule]] = {}
    for r in program.rules:
        by_name.setdefault(r.name, []).append(r)
    options = dataset_options(plant.store, [*inputs, INFERRED])
    for fact, name in outcome.provenance.items():
        queries = [q for r in by_name[name] if (q := r.instances_query(fact)) is not None]
        assert any(list(plant.store.query(q, **options)) for q in queries), (fact, name)


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "engine.cli", "explain", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=120, check=False)


def test_cli_text_json_and_exit_codes(tmp_path: Path) -> None:
    ok = _cli(str(ROBOT_CELL), BRIDGE)
    assert ok.returncode == 0, ok.stderr
    assert R1 in ok.stdout and "Historian database" in ok.stdout and "ROS machine" in ok.stdout

    js = _cli(str(ROBOT_CELL), BRIDGE, "--format", "json")
    assert js.returncode == 0, js.stderr
    doc = json.loads(js.stdout)
    assert doc["required"] is True and R1 in [r["rule"] for r in doc["reasons"]]

    gone = _cli(str(_variant(tmp_path, historian=False, bridges_to=False)), BRIDGE)
    assert gone.returncode == 1, gone.stderr
    assert gone.stdout.startswith(f"{BRIDGE} is not required:")

    bad = _cli(str(ROBOT_CELL), "bridge.mosquitto")
    assert bad.returncode == 2
    assert "'bridge.mosquitto' is not a plan address" in bad.stderr and "Traceback" not in bad.stderr


def test_many_reasons_are_capped_and_say_so(tmp_path: Path) -> None:
    from benchmarks.synthetic import write_file  # noqa: PLC0415

    e = _explain(write_file(100, tmp_path), "broker.broker-0")  # dozens of resources send to it
    assert e.required and len(e.reasons) == MAX_REASONS
    assert f"only the first {MAX_REASONS} reasons" in e.note and e.note in e.text()
