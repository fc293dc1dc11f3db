"""PlantState re-reads changed files, keeps the last good plant when a file breaks, and applies
only the plan a person saw."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from flask.testing import FlaskClient

from engine.web.plant_state import ApplyRefused, PlantState


def touch_with(path: Path, text: str) -> None:
    path.write_text(text, encoding="utf-8")
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))  # a visible mtime change


def test_a_changed_file_is_read_again(state: PlantState, plant_file: Path) -> None:
    before = state.snapshot
    state.tick()  # nothing changed, and the agents were asked less than observe_interval ago
    assert state.snapshot is before
    state.refresh()
    assert state.snapshot.desired == before.desired and state.snapshot.version > before.version
    touch_with(plant_file, plant_file.read_text().replace('pk:port 1883', 'pk:port 1999'))
    state.tick()
    assert state.snapshot.desired.broker("mosquitto").port == 1999
    assert state.snapshot.plant is not before.plant


def test_a_broken_file_keeps_the_last_good_plant(state: PlantState, plant_file: Path, client: FlaskClient) -> None:
    good = state.snapshot
    text = plant_file.read_text()
    touch_with(plant_file, text + "\nthis is not turtle\n")
    state.tick()
    snap = state.snapshot
    assert snap.error and "cannot be loaded" in snap.error and str(plant_file) in snap.error
    assert snap.plant is good.plant and snap.plan is None
    with pytest.raises(ApplyRefused):
        state.start_apply(good.fingerprint)
    assert client.get("/api/status").json["error"] == snap.error
    assert client.get("/sparql", query_string={"query": "ASK { ?b pk:id \"kafka\" }"}).json["boolean"] is True
    touch_with(plant_file, text)
    state.tick()
    assert state.snapshot.error is None and state.snapshot.plan is not None


def test_an_invalid_plant_is_reported_and_not_planned(state: PlantState, plant_file: Path, client: FlaskClient) -> None:
    touch_with(plant_file, plant_file.read_text().replace('pk:ip "127.0.0.3"', 'pk:ip "kafka-host"'))
    state.tick()
    snap = state.snapshot
    assert snap.report is not None and not snap.report.conforms and snap.plan is None
    assert client.get("/api/status").json["validation"]["violations"] >= 1
    assert "has violations" in client.get("/validation").get_data(as_text=True)
    assert "has violations" in client.get("/plan").get_data(as_text=True)


def test_status_etag(client: FlaskClient) -> None:
    first = client.get("/api/status")
    assert first.status_code == 200 and first.headers["ETag"] == f'"{first.json["version"]}"'
    again = client.get("/api/status", headers={"If-None-Match": first.headers["ETag"]})
    assert again.status_code == 304 and again.data == b""
