"""The dashboard's data (engine.web.views), the OpenAPI document and the pages, from engine values."""

from __future__ import annotations

from flask import Flask
from flask.testing import FlaskClient

from engine.model import (Action, BridgeDirection, BridgeEnd, BridgeMechanism, BridgeRoute, BridgeSpec,
                          BridgeStatus, BrokerSpec, BrokerStatus, Change, DesiredState, ObservedBridge,
                          ObservedBroker, ObservedState, ObservedTopic, TopicSpec)
from engine.web import views
from engine.web.dashboard import change_rows
from engine.web.openapi import openapi_document

A = BrokerSpec("a", "urn:a", "A", "mosquitto", "127.0.0.2", 1883)
B = BrokerSpec("b", "urn:b", "B", "mosquitto", "127.0.0.3", 1884)
C = BrokerSpec("c", "urn:c", "C", "kafka", "127.0.0.4", 9092)
BRIDGE = BridgeSpec(BridgeEnd("a", "mosquitto", "127.0.0.2", 1883), BridgeEnd("b", "mosquitto", "127.0.0.3", 1884),
                    BridgeMechanism.MOSQUITTO, (BridgeRoute("t1", BridgeDirection.OUT),))
STRAY = BridgeSpec(BridgeEnd("x", "mosquitto", "127.0.0.9", 1), BridgeEnd("b", "mosquitto", "127.0.0.3", 1884),
                   BridgeMechanism.MOSQUITTO, (BridgeRoute("t9", BridgeDirection.IN),))
DESIRED = DesiredState(brokers=(A, B, C), topics=(TopicSpec("a", "t1", "urn:t1", qos=1), TopicSpec("a", "t2", "urn:t2")),
                       bridges=(BRIDGE,))
OBSERVED = ObservedState(
    brokers=(ObservedBroker(A, BrokerStatus.RUNNING, (ObservedTopic("t1"), ObservedTopic("old")), pid=42,
                            started_at=1000.0, restarts=2),
             ObservedBroker(BrokerSpec("x", "urn:x", "X", "mosquitto", "127.0.0.9", 1), BrokerStatus.CRASHED)),
    unreachable=("127.0.0.4",),
    bridges=(ObservedBridge(BRIDGE, BridgeStatus.RUNNING, forwarded=17, retried=1, restarts=0),
             ObservedBridge(STRAY, BridgeStatus.FAILED, last_error="refused")),
)


def test_broker_rows_say_what_runs_and_what_does_not() -> None:
    rows = {r["id"]: r for r in views.broker_rows(DESIRED, OBSERVED)}
    assert rows["a"]["status"] == "running" and rows["a"]["restarts"] == 2 and rows["a"]["pid"] == 42
    assert (rows["a"]["topics_present"], rows["a"]["topics_wanted"], rows["a"]["topics_extra"]) == (1, 2, 1)
    assert rows["b"]["status"] == "absent" and rows["c"]["status"] == "unknown"
    assert rows["x"]["status"] == "crashed" and not rows["x"]["in_plant"] and rows["x"]["started_at"] is None


def test_bridge_rows_join_the_plant_and_the_agents() -> None:
    rows = {r["address"]: r for r in views.bridge_rows(DESIRED, OBSERVED)}
    ab = rows["bridge.a.b"]
    assert (ab["status"], ab["forwarded"], ab["retried"], ab["mechanism"]) == ("running", 17, 1, "mosquitto")
    assert ab["routes"] == [{"topic": "t1", "direction": "out", "qos": 1}] and ab["in_plant"]
    assert rows["bridge.x.b"]["status"] == "failed" and not rows["bridge.x.b"]["in_plant"]
    assert views.bridge_rows(DESIRED, None)[0]["status"] == "absent"


def test_machines_and_topics() -> None:
    brokers = views.broker_rows(DESIRED, OBSERVED)
    machines = {m["host"]: m for m in views.machine_rows(brokers, OBSERVED, {"127.0.0.2": "http://127.0.0.2:7300"})}
    assert machines["127.0.0.2"]["agent_status"] == "answered" and machines["127.0.0.2"]["brokers"] == ["a"]
    assert machines["127.0.0.4"]["agent_status"] == "unreachable"
    topics = views.topic_rows(DESIRED, OBSERVED)
    assert [(t["name"], t["present"], t["settings"]) for t in topics] == [("t1", True, {"qos": 1}), ("t2", False, {})]


def test_graph_links_resources_brokers_and_bridges() -> None:
    brokers = views.broker_rows(DESIRED, OBSERVED)
    bridges = views.bridge_rows(DESIRED, OBSERVED)
    small = views.graph_elements(brokers, bridges, [views.ResourceLink("r1", "Robot", "a")])
    assert {n["id"] for n in small["nodes"]} >= {"broker:a", "resource:r1"}
    assert {(e["source"], e["target"], e["type"]) for e in small["edges"]} == {
        ("resource:r1", "broker:a", "sends"), ("broker:a", "broker:b", "bridge"),
        ("broker:x", "broker:b", "bridge")}  # x is not in the plant, but it runs: drawn too
    many = [views.ResourceLink(f"r{i}", "", "a" if i % 2 else "b") for i in range(views.GRAPH_RESOURCE_LIMIT + 1)]
    big = views.graph_elements(brokers, bridges, many)
    grouped = [n for n in big["nodes"] if n["type"] == "resource"]
    assert big["aggregated"] and len(grouped) == 2 and {n["label"] for n in grouped} == {"75 resources", "76 resources"}


def test_change_rows_show_before_and_after() -> None:
    change = Change("broker.a", Action.REPLACE, {"port": 1, "name": "A"}, {"port": 2, "name": "A"})
    rows = {r["field"]: r for r in change_rows(change)}
    assert rows["port"] == {"field": "port", "before": "1", "after": "2", "changed": True}
    assert not rows["name"]["changed"]


def test_openapi_describes_every_api_route_and_nothing_more(app: Flask) -> None:
    documented = {(path, method.upper()) for path, ops in openapi_document()["paths"].items() for method in ops}
    served = {(rule.rule, method) for rule in app.url_map.iter_rules()
              if rule.rule.startswith(("/api/", "/sparql"))
              for method in (rule.methods or set()) - {"HEAD", "OPTIONS"}}
    assert documented == served


def test_pages_render(client: FlaskClient) -> None:
    overview = client.get("/").get_data(as_text=True)
    assert 'id="initial-status"' in overview and "third_party/cytoscape/cytoscape.min.js" in overview
    assert "Which resource sends where" in client.get("/query").get_data(as_text=True)
    assert "conforms to the shapes" in client.get("/validation").get_data(as_text=True)
    plan = client.get("/plan").get_data(as_text=True)
    assert "Agent did not answer: 127.0.0.2" in plan and "Agent did not answer: 127.0.0.3" in plan
    assert client.get("/static/third_party/cytoscape/LICENSE").status_code == 200


def test_every_example_query_runs_and_answers(client: FlaskClient) -> None:
    from engine.web.examples import EXAMPLES

    for example in EXAMPLES:
        r = client.post("/sparql", data={"query": example.query},
                        headers={"Accept": "application/sparql-results+json, text/turtle;q=0.9"})
        assert r.status_code == 200, (example.title, r.get_data(as_text=True))
        answered = r.json["results"]["bindings"] if r.mimetype.endswith("json") else r.get_data(as_text=True)
        assert answered, example.title


def test_context_broker_topics_show_their_entity() -> None:
    desired = DesiredState(topics=(TopicSpec("cb", "agv/1/status", "x:t", entity_id="urn:ngsi-ld:AGV:1",
                                             entity_type="AGV"),))
    [row] = views.topic_rows(desired, ObservedState())
    assert row["settings"] == {"entity_id": "urn:ngsi-ld:AGV:1", "entity_type": "AGV"}
