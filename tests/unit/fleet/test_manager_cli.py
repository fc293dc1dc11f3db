"""``plantkg fleet ...`` through the plugin group of the engine's command line (no manager running):
vehicles, pin, rename, remove on a data directory; order without a manager says how to start one;
bad arguments name the value."""

from __future__ import annotations

import json
from pathlib import Path

import click
import pytest
import rdflib

from engine.cli import PLUGIN_GROUP, cli, main
from fleet.discovery.inbox import Interface, VehicleKey
from fleet.discovery.records import DataDir, VehicleRecord
from fleet.manager.service import describe, render_record
from tests.unit.fleet import discovery_data as d

BINDING = {"mqtt_broker_iri": "https://example.org/plant#fleet-mqtt", "context_broker_iri": None,
           "base_iri": "https://example.org/plant#"}
FLEET = rdflib.Namespace("https://w3id.org/plantkg/fleet#")
PK = rdflib.Namespace("https://w3id.org/plantkg/ontology#")


@pytest.fixture
def data(tmp_path: Path) -> DataDir:
    store = DataDir(tmp_path, render_record)
    for serial in ("agv-1", "agv-2"):
        desc = describe(VehicleKey(Interface.VDA5050, "acme", serial), d.factsheet("acme", serial))
        store.save(VehicleRecord("vda5050", "acme", serial, "acme", desc, BINDING, discovered_at="2026-11-24T20:00:00.000Z"))
    return store


def run(capsys: pytest.CaptureFixture[str], *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out = capsys.readouterr()
    return code, out.out, out.err


def test_fleet_is_a_plugin_command_of_plantkg() -> None:
    assert "fleet" in cli.list_commands(click.Context(cli)) and PLUGIN_GROUP == "plantkg.commands"


def test_vehicles_lists_what_was_discovered(data: DataDir, capsys: pytest.CaptureFixture[str]) -> None:
    code, out, _ = run(capsys, "fleet", "vehicles", "--data-dir", str(data.root), "--format", "json")
    assert code == 0
    listed = json.loads(out)
    assert [v["vehicle"] for v in listed["vehicles"]] == ["acme/agv-1", "acme/agv-2"]
    assert listed["refused"] == [] and "pick" in listed["vehicles"][0]["skills"]
    code, out, _ = run(capsys, "fleet", "vehicles", "--data-dir", str(data.root))
    assert code == 0 and "acme/agv-1" in out and "ONLINE" in out


def test_pin_rename_remove_change_the_files(data: DataDir, capsys: pytest.CaptureFixture[str]) -> None:
    assert run(capsys, "fleet", "pin", "agv-1", "--data-dir", str(data.root))[0] == 0
    assert run(capsys, "fleet", "rename", "acme/agv-1", "Carrier one", "--data-dir", str(data.root))[0] == 0
    g = rdflib.Graph().parse(data.discovered / "acme--agv-1.ttl")
    agv = next(g.subjects(FLEET.serialNumber, rdflib.Literal("agv-1")))
    assert (str(g.value(agv, PK.name)), g.value(agv, FLEET.pinned).toPython()) == ("Carrier one", True)
    assert run(capsys, "fleet", "pin", "agv-1", "--unpin", "--data-dir", str(data.root))[0] == 0
    assert data.find("agv-1").pinned is False and data.find("agv-1").name == "Carrier one"
    code, out, _ = run(capsys, "fleet", "remove", "agv-2", "--data-dir", str(data.root))
    assert code == 0 and "acme/agv-2: removed" in out
    assert [p.name for p in data.turtle_files()] == ["acme--agv-1.ttl"]


@pytest.mark.parametrize("args,message", [
    (["fleet", "pin", "nope"], "no discovered vehicle 'nope'"),
    (["fleet", "rename", "agv-1", "two\nlines"], "one line of at most 200 characters"),
    (["fleet", "order", "agv-1", "park-1"], "no fleet manager runs for"),
    (["fleet", "order", "agv-1", "nowhere"], "has no station 'nowhere'"),
])
def test_mistakes_get_a_message_and_exit_2(data: DataDir, capsys: pytest.CaptureFixture[str], args: list[str],
                                           message: str) -> None:
    code, _, err = run(capsys, *args, "--data-dir", str(data.root))
    assert code == 2 and message in err, err


def test_a_missing_data_directory_is_named(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "fleet", "vehicles", "--data-dir", str(tmp_path / "none"))
    assert code == 2 and "no such data directory" in err


def test_status_shows_what_the_manager_wrote(data: DataDir, capsys: pytest.CaptureFixture[str]) -> None:
    status = {"updated": "2026-11-24T20:00:00.000Z",
              "manager": {"pid": 7, "api": "http://127.0.0.1:1", "mqtt": "127.0.0.2:1883", "connected": True},
              "lastReconcile": {"at": "2026-11-24T20:00:00.000Z", "summary": "10 change(s) applied in 0.20 s"},
              "vehicles": [{"vehicle": "acme/agv-1", "connectionState": "ONLINE", "readySeconds": 0.4,
                            "state": {"orderId": "o-1", "lastNodeId": "n2", "batteryCharge": 81.5}}],
              "refused": [{"vehicle": "evil--x", "reason": "speedMax: -2 is not > 0"}],
              "refusedMessages": [{"topic": "uagv/v2/evil/y/factsheet", "reason": "10000002 bytes"}]}
    (data.root / "status.json").write_text(json.dumps(status))
    code, out, _ = run(capsys, "fleet", "status", "--data-dir", str(data.root))
    assert code == 0
    for words in ("connected", "10 change(s) applied", "acme/agv-1", "0.400 s", "last node n2", "battery 81.5",
                  "refused evil--x: speedMax", "refused message on uagv/v2/evil/y/factsheet"):
        assert words in out, (words, out)


def test_manager_and_simulate_options_are_checked(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "fleet", "manager", "plant.ttl")
    assert code == 2 and "--data-dir" in err
    code, _, err = run(capsys, "fleet", "simulate", "--count", "zero")
    assert code == 2 and "--count 'zero'" in err
