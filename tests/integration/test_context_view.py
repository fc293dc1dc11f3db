"""``plantkg serve`` sees the live context: a real context broker's entities appear in the plant's
store (and so in the SPARQL endpoint) next to the plant, are replaced on every observation, and a
context broker that stops answering is reported, its old context gone."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest

from benchmarks.context_broker_rig import ContextBroker
from engine.web.plant_state import PlantState
from tests.web.conftest import closed_directory, make_app

pytestmark = pytest.mark.integration

PLANT = """
@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix :   <https://example.org/live#> .
:cb a pk:Broker ; pk:id "cb" ; pk:name "Context broker" ; pk:brokerType "ngsi-v2" ;
    pk:ip "127.0.0.1" ; pk:port {port} .
:planner a pk:Resource ; pk:id "planner" ; pk:name "Task planner" ; pk:sendsTo :cb .
"""

BATTERY = """SELECT ?value ?broker WHERE {
  ?agv ngsi:entityId "urn:ngsi-ld:AGV:7" ; ngsi:hasAttribute ?attr .
  ?attr ngsi:name "battery" ; ngsi:hasValue ?value .
  ?broker a pk:ContextBroker ; pk:id "cb" }"""
PREFIXES = ""  # ngsi: is predeclared


@pytest.fixture
def broker(tmp_path: Path) -> Iterator[ContextBroker]:
    rig = ContextBroker(tmp_path / "cb").start()
    try:
        yield rig
    finally:
        rig.stop()


def put_battery(rig: ContextBroker, value: float) -> None:
    body = json.dumps({"id": "urn:ngsi-ld:AGV:7", "type": "AGV",
                       "battery": {"type": "Number", "value": value}})
    reply = rig.http().request("POST", "/v2/entities?options=upsert", body,
                               {"Content-Type": "application/json", **rig.auth})
    assert reply.status in (201, 204), reply.body


def test_the_dashboard_store_holds_the_live_context(broker: ContextBroker, tmp_path: Path) -> None:
    plant = tmp_path / "live.ttl"
    plant.write_text(PLANT.replace("{port}", str(broker.port)), encoding="utf-8")
    put_battery(broker, 81.5)
    state = PlantState([str(plant)], None, directory_loader=lambda _p: closed_directory(("127.0.0.1",)))
    app = None
    try:
        state.reload()
        snap = state.snapshot
        assert snap.error is None, snap.error
        assert snap.context is not None and snap.context.quads > 0 and not snap.context.unavailable
        app = make_app(state)
        client = app.test_client()
        answer = client.get("/sparql", query_string={"query": PREFIXES + BATTERY},
                            headers={"Accept": "application/sparql-results+json"}).json
        rows = answer["results"]["bindings"]
        assert [float(r["value"]["value"]) for r in rows] == [81.5]
        assert client.get("/api/status").json["context"]["unavailable"] == []

        put_battery(broker, 42.0)
        state.refresh()
        rows = client.get("/sparql", query_string={"query": PREFIXES + BATTERY},
                          headers={"Accept": "application/sparql-results+json"}).json["results"]["bindings"]
        assert [float(r["value"]["value"]) for r in rows] == [42.0], "the old value must be replaced"

        broker.stop()
        state.refresh()
        context = state.snapshot.context
        assert context is not None and context.quads == 0
        assert [iri for iri, _why in context.unavailable] == ["https://example.org/live#cb"]
        rows = client.get("/sparql", query_string={"query": PREFIXES + BATTERY},
                          headers={"Accept": "application/sparql-results+json"}).json["results"]["bindings"]
        assert rows == []
    finally:
        if app is not None:
            app.extensions["plantkg_sparql"].close()  # the SPARQL worker processes the queries started
        state.close()


def test_plantkg_query_live_sees_inferred_facts_and_context(broker: ContextBroker, tmp_path: Path) -> None:
    from click.testing import CliRunner

    from engine.cli import cli

    plant = tmp_path / "live.ttl"
    plant.write_text(PLANT.replace("{port}", str(broker.port)), encoding="utf-8")
    put_battery(broker, 63.5)
    runner = CliRunner()
    query = PREFIXES + BATTERY
    offline = runner.invoke(cli, ["query", str(plant), "--format", "csv", query])
    assert offline.exit_code == 0 and offline.output.strip() == "value,broker", offline.output
    live = runner.invoke(cli, ["query", str(plant), "--live", "--format", "csv", query])
    assert live.exit_code == 0, live.output
    assert live.output.strip().splitlines()[1:] == ["63.5,https://example.org/live#cb"]
    broker.stop()
    gone = runner.invoke(cli, ["query", str(plant), "--live", "--format", "csv", query])
    assert gone.exit_code == 0 and "could not be read" in gone.output
    lonely = runner.invoke(cli, ["query", str(plant), "--agents", "agents.toml", query])
    assert lonely.exit_code == 2 and "--agents goes with --live" in lonely.output
