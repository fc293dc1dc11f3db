"""fleet.discovery.admission and ``plantkg fleet admit``: a vehicle admitted to a closed broker
before it connects (its password file, record and Turtle), refusals that write nothing, and the
registry's handling of an admitted vehicle when it is heard."""

from __future__ import annotations

import stat
from pathlib import Path
from typing import Any

import pytest
import rdflib

from engine.cli import main
from fleet.discovery.admission import AdmissionError, admit
from fleet.discovery.inbox import ConnectionSeen, DescriptionSeen, Interface, VehicleKey
from fleet.discovery.records import DataDir, VehicleRecord
from fleet.discovery.registry import AskFactsheet, Join, Known, Registry, SetConnection
from fleet.manager.service import describe, render_record
from tests.unit.fleet import discovery_data as d

BINDING = {"mqtt_broker_iri": "https://example.org/plant#fleet-mqtt", "context_broker_iri": None,
           "base_iri": "https://example.org/plant#"}
FLEET = rdflib.Namespace("https://w3id.org/plantkg/fleet#")
PK = rdflib.Namespace("https://w3id.org/plantkg/ontology#")
ROOT = Path(__file__).resolve().parents[3]
KEY = VehicleKey(Interface.VDA5050, d.MANUFACTURER, d.SERIAL)


def test_admit_writes_a_0600_password_and_the_vehicle_with_its_secret_ref(tmp_path: Path) -> None:
    data = DataDir(tmp_path / "data", render_record)
    secret = tmp_path / "agv-42.pw"
    done = admit(data, BINDING, "vda5050", d.MANUFACTURER, d.SERIAL, secret)
    assert done.user == f"agv-{d.SERIAL}" and done.secret_file == secret
    assert stat.S_IMODE(secret.stat().st_mode) == 0o600 and len(secret.read_text().strip()) >= 40
    [record] = data.records()
    assert record.awaiting_description and record.secret_ref == f"file:{secret}"
    assert record.connection_state == "OFFLINE" and record.description["skills"] == []
    g = rdflib.Graph().parse(done.turtle, format="turtle")
    agv = rdflib.URIRef(f"https://example.org/plant#agv-{d.SERIAL}")
    assert g.value(agv, PK.secretRef) == rdflib.Literal(f"file:{secret}")
    assert g.value(agv, FLEET.discovered) == rdflib.Literal(False)
    assert g.value(agv, PK.id) == rdflib.Literal(done.user)
    published = {str(g.value(t, FLEET.channel)) for t in g.objects(agv, PK.publishes)}
    subscribed = {str(g.value(t, FLEET.channel)) for t in g.objects(agv, PK.subscribes)}
    assert published == {"state", "visualization", "connection", "factsheet"}
    assert subscribed == {"order", "instantActions"}
    assert secret.read_text().strip() not in done.turtle.read_text() + (data.vehicles / f"{record.stem}.json").read_text()


def _known(tmp_path: Path) -> DataDir:
    data = DataDir(tmp_path / "data", render_record)
    desc = describe(KEY, d.factsheet())
    data.save(VehicleRecord("vda5050", d.MANUFACTURER, d.SERIAL, d.MANUFACTURER, desc, BINDING))
    return data


REFUSALS: list[tuple[str, dict[str, Any], str]] = [
    ("bad serial", {"serial": "has space"}, "cannot be admitted"),
    ("serial with a slash", {"serial": "a/b"}, "cannot be admitted"),
    ("bad interface", {"interface": "opcua"}, "is not one of"),
    ("secret file exists", {"existing_secret": True}, "never writes over one"),
    ("secret folder missing", {"secret": "no-such-folder/pw"}, "its folder does not exist"),
    ("discovered already", {"known": True}, "is discovered already"),
]


@pytest.mark.parametrize(("case", "change", "message"), REFUSALS, ids=[c[0] for c in REFUSALS])
def test_a_refused_admission_writes_nothing(tmp_path: Path, case: str, change: dict[str, Any], message: str) -> None:
    data = _known(tmp_path) if change.get("known") else DataDir(tmp_path / "data", render_record)
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    secret = tmp_path / change.get("secret", "pw")
    if change.get("existing_secret"):
        secret.write_text("the vehicle's old password\n")
        before[secret] = secret.read_bytes()
    with pytest.raises(AdmissionError, match=message):
        admit(data, BINDING, change.get("interface", "vda5050"), d.MANUFACTURER, change.get("serial", d.SERIAL), secret)
    after = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file() and p.name != ".lock"}
    assert after == {p: b for p, b in before.items() if p.name != ".lock"}, case


def test_admitting_twice_is_refused_and_keeps_the_first_password(tmp_path: Path) -> None:
    data = DataDir(tmp_path / "data", render_record)
    first = admit(data, BINDING, "vda5050", d.MANUFACTURER, d.SERIAL, tmp_path / "one.pw")
    with pytest.raises(AdmissionError, match="is admitted already"):
        admit(data, BINDING, "vda5050", d.MANUFACTURER, d.SERIAL, tmp_path / "two.pw")
    assert not (tmp_path / "two.pw").exists() and first.secret_file.exists()


def test_its_first_factsheet_fills_it_in_and_keeps_the_secret_ref(tmp_path: Path) -> None:
    """The registry asks an admitted vehicle's factsheet when it says ONLINE (rate-limited like an
    unknown one) and joins its description as new."""
    data = DataDir(tmp_path / "data", render_record)
    admit(data, BINDING, "vda5050", d.MANUFACTURER, d.SERIAL, tmp_path / "pw")
    [record] = data.records()
    r = Registry(describe, ask_every=5.0)
    r.load({KEY: Known(record.description, record.connection_state, record.pinned, record.awaiting_description)})
    assert r.handle(ConnectionSeen(KEY, "ONLINE"), 0.0) == [SetConnection(KEY, "ONLINE"), AskFactsheet(KEY)]
    assert r.handle(ConnectionSeen(KEY, "ONLINE"), 1.0) == []  # asked a second ago
    [join] = r.handle(DescriptionSeen(KEY, d.factsheet()), 1.1)
    assert isinstance(join, Join) and join.new and "pick" in join.description["skills"]
    assert r.handle(ConnectionSeen(KEY, "ONLINE"), 10.0) == []  # heard: no more requests
    assert r.handle(DescriptionSeen(KEY, d.factsheet()), 10.1) == []


def test_a_known_vehicle_that_was_not_admitted_is_not_asked_again() -> None:
    r = Registry(describe, ask_every=5.0)
    r.load({KEY: Known(describe(KEY, d.factsheet()), "OFFLINE")})
    assert r.handle(ConnectionSeen(KEY, "ONLINE"), 0.0) == [SetConnection(KEY, "ONLINE")]


def test_plantkg_fleet_admit(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    plant = ROOT / "ontology" / "examples" / "agv-fleet.ttl"
    secret = tmp_path / "sim-0002.pw"
    code = main(["fleet", "admit", "sim-0002", str(plant), "--manufacturer", "plantkg-sim",
                 "--secret-file", str(secret), "--data-dir", str(tmp_path / "data")])
    out = capsys.readouterr()
    assert code == 0, out.err
    assert "admitted as user agv-sim-0002" in out.out and secret.read_text().strip() not in out.out + out.err
    code = main(["fleet", "vehicles", "--data-dir", str(tmp_path / "data")])
    assert code == 0 and "admitted (not heard yet)" in capsys.readouterr().out
    code = main(["fleet", "admit", "sim-0002", str(plant), "--manufacturer", "plantkg-sim",
                 "--secret-file", str(tmp_path / "other.pw"), "--data-dir", str(tmp_path / "data")])
    assert code == 2 and "is admitted already" in capsys.readouterr().err
