"""An incremental re-plan (engine.incremental.replan) gives exactly what a full run gives, edit after edit.

A synthetic plant (benchmarks.synthetic) is edited by a seeded random sequence of small edits —
renames, values that break a shape and values that mend it, subscriptions that make a bridge and
removals that unmake it, statements added and deleted, a broker's type changed, a class axiom, a
multi-line string and a blank node (which the statement cut cannot read, so the whole file is
compared), a type that clashes — and after each one the session's report, inferred graph and
desired state must equal those of ``run_pipeline`` on the edited file, loaded afresh. Each edit
kind is also checked to have taken the path it is meant to exercise.
"""

from __future__ import annotations

import random
import re
from collections import Counter
from pathlib import Path
from typing import Callable

import pytest

from benchmarks import synthetic
from engine.model import BridgeStatus, BrokerStatus, ObservedBridge, ObservedBroker, ObservedState, ObservedTopic
from engine.pipeline import run_pipeline
from engine.plan import plan
from engine.reasoning.reason import INFERRED
from engine.incremental.replan import ReplanSession
from kg.file_delta import FileText, turtle_delta

N = 60
SEED = 1616
EDITS_PER_RUN = 36

Edit = Callable[[str, random.Random], str | None]


def _sub(pattern: str, repl: str, text: str) -> str | None:
    new, n = re.subn(pattern, repl, text, count=1)
    return new if n else None


def rename_resource(text: str, rng: random.Random) -> str | None:
    i = rng.randrange(N)
    return _sub(rf'pk:name "Sensor {i}"', f'pk:name "Sensor {i} (moved)"', text)


def break_topic_name(text: str, rng: random.Random) -> str | None:
    """A space in a topic name: MQTT and Kafka shapes report it."""
    i = rng.randrange(N)
    return _sub(rf'pk:name "plant\.sensor-{i}\.value"', f'pk:name "plant sensor {i}"', text)


def mend_topic_name(text: str, rng: random.Random) -> str | None:
    found = re.findall(r'pk:name "plant sensor (\d+)"', text)
    if not found:
        return None
    i = rng.choice(found)
    return _sub(rf'pk:name "plant sensor {i}"', f'pk:name "plant.sensor-{i}.value"', text)


def kafka_collision(text: str, rng: random.Random) -> str | None:
    """A topic of a Kafka broker renamed to another of its topics' name with . written _: Kafka
    treats the two as one (pks:Topic-kafkaCollision, a grouped sub-query)."""
    brokers = max(1, -(-N // 20))
    kafka = [b for b in range(brokers) if b % 2 == 1]
    if not kafka:
        return None
    b = rng.choice(kafka)
    mine = [i for i in range(N) if i % brokers == b]
    i, j = rng.sample(mine, 2)
    return _sub(rf'pk:name "plant\.sensor-{i}\.value"', f'pk:name "plant_sensor-{j}_value"', text)


def subscribe_across(text: str, rng: random.Random) -> str | None:
    """A resource subscribes to a topic published on another broker, which its broker then
    carries: rule R1 requires a bridge."""
    i, j = rng.randrange(N), rng.randrange(N)
    brokers = max(1, -(-N // 20))
    if i % brokers == j % brokers or f"pk:subscribes :topic{j} " in text:
        return None
    new = _sub(rf"(:res{i} a pk:Resource ;)", rf"\1 pk:subscribes :topic{j} ;", text)
    return None if new is None else new + f":broker{i % brokers} pk:hasTopic :topic{j} .\n"


def unsubscribe(text: str, rng: random.Random) -> str | None:
    found = re.findall(r"(:res\d+ a pk:Resource ; pk:subscribes :topic\d+ ;)", text)
    if not found:
        return None
    line = rng.choice(found)
    return text.replace(line, line.split(" pk:subscribes")[0] + " ;", 1)


def drop_carried(text: str, rng: random.Random) -> str | None:
    """A broker no longer carries a topic its publisher sends: a violation (and one less topic)."""
    found = re.findall(r"^:broker\d+ pk:hasTopic :topic\d+ \.\n", text, flags=re.M)
    return text.replace(rng.choice(found), "", 1) if found else None


def duplicate_id(text: str, rng: random.Random) -> str | None:
    i, j = rng.randrange(N), rng.randrange(N)
    return None if i == j else _sub(rf'pk:id "res-{i}"', f'pk:id "res-{j}"', text)


def restore_ids(text: str, rng: random.Random) -> str | None:
    """Every resource gets its own id back (mends duplicate_id)."""
    new = re.sub(r':res(\d+) a pk:Resource ; pk:id "res-\d+"', r':res\1 a pk:Resource ; pk:id "res-\1"', text)
    return new if new != text else None


def bad_port(text: str, rng: random.Random) -> str | None:
    b = rng.randrange(3)
    return _sub(rf'(:broker{b} a pk:Broker [^\n]*pk:port )\d+', r"\g<1>70000", text)


def good_port(text: str, rng: random.Random) -> str | None:
    return _sub(r"pk:port 70000", "pk:port 1884", text)


def switch_broker_type(text: str, rng: random.Random) -> str | None:
    b = rng.randrange(3)
    line = re.search(rf':broker{b} a pk:Broker [^\n]*pk:brokerType "(\w+)"', text)
    if not line:
        return None
    other = "kafka" if line.group(1) == "mosquitto" else "mosquitto"
    return text.replace(line.group(0), line.group(0).replace(f'"{line.group(1)}"', f'"{other}"'), 1)


def add_resource(text: str, rng: random.Random) -> str | None:
    k = rng.randrange(1000, 2000)
    if f":extra{k} " in text:
        return None
    t = rng.randrange(N)
    return text + (f':extra{k} a pk:Resource ; pk:id "extra-{k}" ; pk:name "Extra {k}" ; '
                   f"pk:isType :type-sensor ; pk:sendsTo :broker{t % 3} ; pk:subscribes :topic{t} .\n"
                   f":broker{t % 3} pk:hasTopic :topic{t} .\n")


def delete_resource(text: str, rng: random.Random) -> str | None:
    found = re.findall(r"^:(?:res|extra)\d+ a pk:Resource ;[^\n]*\n(?:[^:\n][^\n]*\n)*", text, flags=re.M)
    return text.replace(rng.choice(found), "", 1) if found else None


def subclass_axiom(text: str, rng: random.Random) -> str | None:
    """A class axiom in the plant file: a sensor class under pk:Resource (the TBox changes); the
    second time it is taken back."""
    axiom = "pk:SensorThing rdfs:subClassOf pk:Resource .\n"
    if axiom in text:
        return text.replace(":res3 a pk:SensorThing ;", ":res3 a pk:Resource ;").replace(axiom, "")
    if "@prefix rdfs:" not in text:
        text = text.replace("@prefix xsd:", "@prefix rdfs: <http://www.w3.org/2000/01/rdf-schema#> .\n@prefix xsd:", 1)
    return text.replace(":res3 a pk:Resource ;", ":res3 a pk:SensorThing ;", 1) + axiom


def long_description(text: str, rng: random.Random) -> str | None:
    """A multi-line string: the statement cut cannot read the file, the whole file is compared."""
    i = rng.randrange(N)
    if ':res%d pk:description """' % i in text:
        return None
    return text + ':res%d pk:description """two\nlines""" .\n' % i


def blank_node(text: str, rng: random.Random) -> str | None:
    i = rng.randrange(N)
    return text + f":res{i} pk:hasProperty [ a pk:Property ; pk:id \"p-{i}-{rng.randrange(99)}\" ; pk:name \"P\" ] .\n"


def type_clash(text: str, rng: random.Random) -> str | None:
    """A resource typed a broker too: the disjointness shape reports it (the plant is invalid)."""
    i = rng.randrange(N)
    return _sub(rf"(:res{i} a pk:Resource)", r"\1 , pk:Broker", text)


def mend_clash(text: str, rng: random.Random) -> str | None:
    return _sub(r"a pk:Resource , pk:Broker", "a pk:Resource", text)


EDITS: list[Edit] = [rename_resource, break_topic_name, mend_topic_name, kafka_collision, subscribe_across, unsubscribe,
                     drop_carried, duplicate_id, restore_ids, bad_port, good_port, switch_broker_type,
                     add_resource, delete_resource, subclass_axiom, long_description, blank_node,
                     type_clash, mend_clash]


@pytest.fixture(autouse=True)
def own_cache(tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PLANTKG_CACHE_DIR", str(tmp_path_factory.getbasetemp() / "plantkg-cache"))


def _inferred(store) -> set:  # noqa: ANN001
    return {(q.subject, q.predicate, q.object) for q in store.quads_for_pattern(None, None, None, INFERRED)}


def _results(report) -> Counter:  # noqa: ANN001
    """The results with blank node labels erased (a file read again gets new ones), and files."""
    return Counter((r.key(), r.file) for r in report.results)


def _observed_as(desired) -> ObservedState:  # noqa: ANN001
    """What agents running ``desired`` would report (the state before the edit, for the plan)."""
    if desired is None:
        return ObservedState(())
    return ObservedState(tuple(
        ObservedBroker(b, BrokerStatus.RUNNING, tuple(
            ObservedTopic(t.name, t.partitions, t.replication_factor, t.retention_ms, t.qos, t.retain,
                          owner=desired.owner) for t in desired.topics_of(b.id)), owner=desired.owner)
        for b in desired.brokers),
        bridges=tuple(ObservedBridge(b, BridgeStatus.RUNNING, owner=desired.owner) for b in desired.bridges))


def _same_as_full(session: ReplanSession, path: Path | list[Path]) -> None:
    """The session's refresh equals a full run — report, inferred graph, desired state, and the
    plan against what the agents ran before the edit; a plant the full run refuses (a bridge no
    mechanism supports, say) the session refuses with the same error. A list of files is the
    plant's file set now (the session is told it)."""
    observed = _observed_as(session.result.desired)
    files = path if isinstance(path, list) else None
    try:
        full = run_pipeline(files or [path], observe=False)
    except Exception as exc:  # noqa: BLE001 - whatever the full run raises, the session must too
        with pytest.raises(type(exc)) as raised:
            session.refresh(observed, files=files)
        assert str(raised.value) == str(exc)
        return
    got = session.refresh(observed, files=files)
    if full.desired is not None:
        assert got.plan == plan(full.desired, observed)
    assert _results(got.report) == _results(full.report)
    assert got.report.conforms == full.report.conforms
    assert got.desired == full.desired
    if full.report.conforms:
        assert _inferred(session.plant.store) == _inferred(full.plant.store)


def test_random_edits_replan_as_a_full_run_does(tmp_path: Path) -> None:
    """Each step applies a random edit; an edit that makes the plant invalid is then taken back
    (an edit of its own, both compared), and so is a valid one now and then, so the sequence
    keeps moving between valid and invalid plants, bridged and not."""
    path = synthetic.write_file(N, tmp_path)
    session = ReplanSession([path])
    rng = random.Random(SEED)
    text = valid = path.read_text()
    kinds: dict[str, int] = {}
    paths: set[str] = set()
    conforms: set[bool] = set()
    routes: set[int] = set()
    done = 0

    def step(new: str) -> None:
        path.write_text(new)
        _same_as_full(session, path)
        paths.update(session.last["cut"])  # type: ignore[arg-type]
        conforms.add(session.result.report.conforms)
        if session.result.desired is not None:
            routes.add(sum(len(b.routes) for b in session.result.desired.bridges))

    while done < EDITS_PER_RUN:
        edit = rng.choice(EDITS)
        new = edit(text, rng)
        if new is None or new == text:
            continue
        text = new
        step(text)
        done += 1
        kinds[edit.__name__] = kinds.get(edit.__name__, 0) + 1
        if session.result.report.conforms and rng.random() > 0.3:
            valid = text
        else:
            text = valid
            step(text)
    assert conforms == {True, False}, "edits both add and remove violations"
    assert len(routes) > 1, "edits make and unmake bridged topics"
    assert paths == {"cut", "file"}, "both ways of reading an edit are exercised"
    assert len(kinds) >= 12, kinds


@pytest.mark.parametrize("edit", [subscribe_across, unsubscribe, drop_carried, duplicate_id, add_resource,
                                  delete_resource, switch_broker_type, rename_resource, kafka_collision])
def test_each_edit_kind_matches_a_full_run(tmp_path: Path, edit: Edit) -> None:
    path = synthetic.write_file(N, tmp_path)
    session = ReplanSession([path])
    rng = random.Random(SEED)
    text = path.read_text()
    for _ in range(3):
        new = None
        while new is None:
            new = edit(text, rng) if edit is not unsubscribe else (unsubscribe(text, rng) or subscribe_across(text, rng))
        text = new
        path.write_text(text)
        derived_before = session.result.desired is not None
        _same_as_full(session, path)
        assert session.last["cut"] == ["cut"], "a one-statement edit is read from the statement"
        if derived_before and session.result.desired is not None:
            assert session.last["full"] == [], "a valid one-statement edit is done incrementally"


def test_the_statement_cut_equals_comparing_whole_files(tmp_path: Path) -> None:
    """turtle_delta on its own: what it reads from the cut is the difference of the parsed files,
    including a triple another statement still asserts (it stays)."""
    import pyoxigraph as ox

    path = tmp_path / "p.ttl"
    head = "@prefix : <urn:x#> .\n"
    old = head + ":a :p :b .\n:a :q 1 ;\n   :r \"x\" .\n:c :p :a .\n:a :q 1 .\n"
    new = head + ":a :p :b .\n:a :r \"y\" .\n:c :p :a .\n:a :q 1 .\n"
    path.write_text(old)
    cut = turtle_delta(path, FileText.read(path), new.encode())
    assert cut is not None
    delta, _ = cut

    def parsed(text: str) -> set:
        return {(q.subject, q.predicate, q.object) for q in ox.parse(input=text, format=ox.RdfFormat.TURTLE)}

    before, after = parsed(old), parsed(new)
    assert set(delta.removed) == before - after
    assert set(delta.added) == after - before
    assert (ox.NamedNode("urn:x#a"), ox.NamedNode("urn:x#q"), ox.Literal("1", datatype=ox.NamedNode(
        "http://www.w3.org/2001/XMLSchema#integer"))) not in delta.removed


def test_a_grouped_subquery_is_restricted_to_the_focus_nodes_values(tmp_path: Path, monkeypatch) -> None:  # noqa: ANN001
    """pks:Topic-kafkaCollision groups every Kafka broker's topics in a sub-query; re-run for the
    topics an edit reaches, the sub-query is restricted to their brokers (kg.subquery_reduce),
    and the collision it finds is the full run's."""
    from kg import subquery_reduce

    rewritten: list[str] = []
    real = subquery_reduce.reduce_subqueries

    def spy(query, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN202
        out = real(query, *args, **kwargs)
        if out != query:
            rewritten.append(out)
        return out

    monkeypatch.setattr("kg.validate_delta.reduce_subqueries", spy)
    path = synthetic.write_file(N, tmp_path)
    session = ReplanSession([path])
    text = kafka_collision(path.read_text(), random.Random(SEED))
    assert text is not None
    path.write_text(text)
    _same_as_full(session, path)
    assert any(r.shape.endswith("Topic-kafkaCollision") for r in session.result.report.results)
    assert any("VALUES ?broker" in q for q in rewritten)


def test_a_plant_with_a_kafka_cluster_derives_in_full_and_matches(tmp_path: Path) -> None:
    """A cluster joins its nodes across brokers (voters, bootstrap, lead node), which per-broker
    parts cannot hold: after an edit of such a plant the session derives in full, and its answer
    is still the full run's."""
    source = Path(__file__).parents[2] / "ontology" / "examples" / "kafka-cluster.ttl"
    path = tmp_path / "kafka-cluster.ttl"
    text = source.read_text()
    path.write_text(text)
    session = ReplanSession([path])
    assert session.result.desired is not None and any(b.kafka for b in session.result.desired.brokers)
    edited = _sub(r'pk:minInsyncReplicas 2', 'pk:minInsyncReplicas 1', text)
    assert edited is not None, "the example's cluster sets pk:minInsyncReplicas 2"
    path.write_text(edited)
    _same_as_full(session, path)
    assert "derive" in session.last["full"]


def test_files_added_and_removed_replan_as_a_full_run_does(tmp_path: Path) -> None:
    """The fleet manager writes one file per discovered vehicle into the plant's folder: a session
    told the new file set reads an added file whole and takes a removed one out whole, and still
    answers as a full run over the same files — a joining resource that makes a bridge, one that
    breaks a shape, its removal, an empty file and one that does not parse (refused as loading
    refuses them)."""
    path = synthetic.write_file(N, tmp_path)
    session = ReplanSession([path])
    head = synthetic.HEADER.split(":type-sensor")[0]
    joins = tmp_path / "joins"
    joins.mkdir()
    first, second = joins / "agv-1.ttl", joins / "agv-2.ttl"
    first.write_text(head + ':agv1 a pk:Resource ; pk:id "agv-1" ; pk:name "AGV 1" ; pk:isType :type-sensor ; '
                     "pk:sendsTo :broker0 ; pk:subscribes :topic1 .\n:broker0 pk:hasTopic :topic1 .\n")
    before = sum(len(b.routes) for b in session.result.desired.bridges)
    _same_as_full(session, [path, first])
    assert session.last["cut"] == ["file"] and session.files == [path, first]
    assert sum(len(b.routes) for b in session.result.desired.bridges) > before  # its subscription is bridged
    second.write_text(head + ':agv2 a pk:Resource ; pk:id "res-3" ; pk:name "AGV 2" ; pk:sendsTo :broker0 .\n')
    _same_as_full(session, [path, first, second])  # a duplicate pk:id: the plant is invalid
    assert not session.result.report.conforms
    _same_as_full(session, [path, first])  # taken out again: valid
    assert session.result.report.conforms and session.files == [path, first]
    _same_as_full(session, [path])
    assert sum(len(b.routes) for b in session.result.desired.bridges) == before
    _same_as_full(session, [first, path])  # the same files in another order
    empty = joins / "empty.ttl"
    empty.write_text(head)
    _same_as_full(session, [path, first, empty])  # "holds no triples", as loading says
    broken = joins / "broken.ttl"
    broken.write_text(head + ":x a pk:Resource , .\n")
    fresh = ReplanSession([path])
    _same_as_full(fresh, [path, broken])  # the loader's syntax error, naming the file and line


def test_an_edit_too_large_to_follow_is_done_from_scratch_and_still_matches(tmp_path: Path) -> None:
    """More than 1/LARGE_EDIT of the plant's triples changed: loading afresh is cheaper than
    following the edit (a vehicle of 240 triples joining a small plant). Whether the change is
    read from the statements, found by comparing the whole file, or a whole file added, the
    answer is a full run's; a small edit after it is followed again."""
    from engine.incremental.replan import FEW_TRIPLES, LARGE_EDIT

    path = synthetic.write_file(N, tmp_path)
    session = ReplanSession([path])
    text = path.read_text()
    rng = random.Random(SEED)
    big = text
    while big.count(":extra") < 8:
        big = add_resource(big, rng) or big
    assert 8 * 9 * LARGE_EDIT > session.plant.triple_count and 8 * 9 > FEW_TRIPLES  # large for this plant
    path.write_text(big)
    _same_as_full(session, path)
    assert "load" in session.last["full"] and session.last["large_edit"] is not None
    path.write_text(text)  # the eight taken out, whole-file path or cut: again from scratch
    _same_as_full(session, path)
    assert "load" in session.last["full"]
    extra = tmp_path / "extra.ttl"
    extra.write_text(synthetic.HEADER.split(":type-sensor")[0] + big[len(text):])
    _same_as_full(session, [path, extra])  # a large file added: known by its size, not parsed twice
    assert "load" in session.last["full"] and session.last["large_edit"] is None
    path.write_text(text.replace('pk:name "Sensor 5"', 'pk:name "Sensor five"'))
    _same_as_full(session, [path, extra])
    assert session.last["full"] == [] and session.last["cut"] == ["cut"]
