"""``plantkg query``: tables for people, CSV/JSON for programs, queries from files, bindings."""

from __future__ import annotations

import csv
import io
import json

import click

from tests.cli.conftest import EXAMPLES

CELL = EXAMPLES / "robot-cell.ttl"
BROKERS = "SELECT ?broker ?type ?ip ?port WHERE { ?broker a pk:Broker ; pk:brokerType ?type ; pk:ip ?ip ; pk:port ?port } ORDER BY ?ip"


def test_table(plantkg) -> None:
    run = plantkg("query", CELL, BROKERS)
    assert run.code == 0, run.err
    lines = click.unstyle(run.out).splitlines()
    assert lines[0].split() == ["broker", "type", "ip", "port"]
    assert lines[2].split() == ["rc:mosquitto", "mosquitto", "127.0.0.2", "1883"]
    assert lines[3].split() == ["rc:kafka", "kafka", "127.0.0.3", "9092"]
    assert lines[-1] == "(2 rows)"


def test_csv_and_json(plantkg) -> None:
    rows = list(csv.reader(io.StringIO(plantkg("query", CELL, "--format", "csv", BROKERS).out)))
    assert rows[0] == ["broker", "type", "ip", "port"]
    assert rows[1] == ["https://w3id.org/plantkg/examples/robot-cell#mosquitto", "mosquitto", "127.0.0.2", "1883"]
    data = json.loads(plantkg("query", CELL, "--format", "json", BROKERS).out)
    assert [b["port"]["value"] for b in data["results"]["bindings"]] == ["1883", "9092"]


def test_query_file_and_binding(plantkg, write) -> None:
    q = write("q.rq", "SELECT ?broker WHERE { ?broker pk:ip ?ip }\n")
    run = plantkg("query", CELL, "--file", q, "--bind", "ip=127.0.0.3", "--format", "csv")
    assert run.code == 0, run.err
    assert run.out.split() == ["broker", "https://w3id.org/plantkg/examples/robot-cell#kafka"]


def test_ask(plantkg) -> None:
    run = plantkg("query", CELL, "ASK { ?b a pk:Broker ; pk:brokerType 'kafka' }")
    assert (run.code, run.out.strip()) == (0, "yes")


def test_query_sees_the_ontology(plantkg) -> None:
    run = plantkg("query", CELL, "--format", "csv", "SELECT ?label WHERE { pk:Topic skos:altLabel ?label }".replace(
        "skos:altLabel", "<http://www.w3.org/2004/02/skos/core#altLabel>"))
    assert "Topic_sub" in run.out
