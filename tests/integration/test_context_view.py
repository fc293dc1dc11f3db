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


def test_a_closed_context_broker_is_read_with_its_agents_token(tmp_path: Path) -> None:
    """A context broker with principals answers 401 to a read without a token: the dashboard (and
    ``plantkg query --live``) read it with its agent's token, from the agents file (issue 13)."""
    from click.testing import CliRunner

    from engine.agents_config import AgentDirectory, AgentEntry
    from engine.cli import cli
    from engine.security.ngsi_principals import render_principals

    principals = tmp_path / "principals.json"
    principals.write_text(render_principals({"planner": ("planner-Token-51be02", (), ())}), encoding="utf-8")
    principals.chmod(0o600)
    rig = ContextBroker(tmp_path / "cb", extra_args=("--principals", str(principals))).start()
    state = None
    try:
        put_battery(rig, 77.5)
        assert rig.http().request("GET", "/plantkg/v1/graph", None, {}).status == 401  # closed, reads too
        plant = tmp_path / "live.ttl"
        plant.write_text(PLANT.replace("{port}", str(rig.port)), encoding="utf-8")
        agents = {"127.0.0.1": AgentEntry("127.0.0.1", f"http://127.0.0.1:{rig.port + 1}", token=rig.token)}
        state = PlantState([str(plant)], None, directory_loader=lambda _p: AgentDirectory(entries=agents))
        state.reload()
        context = state.snapshot.context
        assert context is not None and context.quads > 0 and context.unavailable == (), context
        with state.store_lock.reading():
            rows = list(state.snapshot.plant.store.query(
                'PREFIX ngsi: <https://w3id.org/plantkg/ngsi#> '
                'SELECT ?v WHERE { GRAPH ?g { ?a ngsi:name "battery" ; ngsi:hasValue ?v } }'))
        assert [float(r["v"].value) for r in rows] == [77.5]

        # without the agent's token (another agent's), the read is refused and reported as such
        agents["127.0.0.1"] = AgentEntry("127.0.0.1", f"http://127.0.0.1:{rig.port + 1}", token="y" * 20)
        state.refresh()
        context = state.snapshot.context
        assert context is not None and context.quads == 0
        assert [why for _iri, why in context.unavailable] == [
            f"ValueError: http://127.0.0.1:{rig.port}/plantkg/v1/graph answered HTTP 401"]

        agents_file = tmp_path / "agents.toml"
        agents_file.write_text(f'[agents."127.0.0.1"]\nurl = "http://127.0.0.1:{rig.port + 1}"\n'
                               f'token = "{rig.token}"\n', encoding="utf-8")
        live = CliRunner().invoke(cli, ["query", str(plant), "--live", "--agents", str(agents_file),
                                        "--format", "csv", PREFIXES + BATTERY])
        assert live.exit_code == 0 and "could not be read" not in live.output, live.output
        assert live.output.strip().splitlines()[-1] == "77.5,https://example.org/live#cb", live.output
        assert rig.token not in live.output
    finally:
        if state is not None:
            state.close()
        rig.stop()
