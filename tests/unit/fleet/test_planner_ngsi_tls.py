"""How the planner trusts an ``https://`` context broker (fleet/planner/ngsi_tls.py), on a real
TLS server whose certificate a test plant CA signed: ``--ngsi-ca-file`` and ``--ngsi-url`` as
cases (a CA file beside ``http://`` is a usage error naming the option); each of the planner's
NGSI clients (the paper's channels, the Task entities, the Event subscription) talks HTTPS trusting
that CA; the system's store refuses the certificate and each client says so (which option to give),
and ``python -m fleet.planner`` exits 2 before it touches its data directory."""

from __future__ import annotations

import json
import ssl
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

import fleet.lotlan
from engine.context_broker.http_server import HttpServer
from engine.process import wait_until
from engine.netutil import free_port
from engine.security import ca
from fleet.planner import build
from fleet.planner.__main__ import main
from fleet.planner.errors import PlannerError
from fleet.planner.events_ngsi import ContextBrokerError, NgsiEvents
from fleet.planner.ngsi import TaskPublisher
from fleet.planner.ngsi_tls import CA_OPTION, NgsiTrust, check_certificate, plant_trust, trust_of, untrusted
from kg.load import load_plant
from fleet.planner.paper import NgsiClient
from tests.unit.context_broker.test_http_server_tls import tls_served
from tests.unit.fleet.planner_data import JOBS, SITE
from tests.unit.fleet.test_planner_cli import EXAMPLE, MAP

HOST = "127.0.0.1"
ENTITY = "urn:ngsi-ld:Thing:t1:motion_channel"


class Store:
    """A WSGI app keeping entity attributes by id and subscriptions (just what the planner's
    clients ask: write and read an entity, a batch update, list and create subscriptions)."""

    def __init__(self) -> None:
        self.entities: dict[str, dict[str, Any]] = {}
        self.subscriptions: list[dict[str, Any]] = []

    def __call__(self, environ: dict[str, Any], start_response: Any) -> list[bytes]:
        path, method = environ["PATH_INFO"], environ["REQUEST_METHOD"]
        size = int(environ.get("CONTENT_LENGTH") or 0)
        body = json.loads(environ["wsgi.input"].read(size)) if size else None
        status, answer = "404 Not Found", {"error": "NotFound", "description": path}
        headers = []
        if method == "POST" and path == "/v2/entities":
            self.entities[body["id"]] = {k: v["value"] for k, v in body.items() if isinstance(v, dict)}
            status, answer = "201 Created", None
        elif method == "POST" and path == "/v2/op/update":
            for entity in body["entities"]:
                self.entities[entity["id"]] = {k: v["value"] for k, v in entity.items() if isinstance(v, dict)}
            status, answer = "204 No Content", None
        elif path == "/v2/subscriptions":
            if method == "POST":
                self.subscriptions.append({**body, "id": f"{len(self.subscriptions):024x}"})
                headers = [("Location", f"/v2/subscriptions/{self.subscriptions[-1]['id']}")]
            status, answer = ("201 Created", None) if method == "POST" else ("200 OK", self.subscriptions)
        elif method == "GET" and path.startswith("/v2/entities/") and path[13:] in self.entities:
            status, answer = "200 OK", {"id": path[13:], **self.entities[path[13:]]}
        data = b"" if answer is None else json.dumps(answer).encode()
        start_response(status, [("Content-Type", "application/json"), ("Content-Length", str(len(data))), *headers])
        return [data]


@pytest.fixture
def plant_ca(tmp_path: Path) -> ca.Ca:
    return ca.load_or_create_ca(tmp_path / "plant-ca")


@pytest.fixture
def broker(tmp_path: Path, plant_ca: ca.Ca) -> Iterator[HttpServer]:
    with tls_served(Store(), tmp_path, plant_ca) as srv:
        yield srv


REFUSED = [  # (id, --ngsi-url, --ngsi-ca-file, expected in the error)
    ("a CA file beside http://", "http://127.0.0.1:1026", Path("/ca.pem"), "--ngsi-ca-file /ca.pem: a CA certificate"),
    ("not http(s)", "ftp://127.0.0.1:1026", None, "--ngsi-url 'ftp://127.0.0.1:1026'"),
    ("a port out of range", "https://127.0.0.1:99999", None, "--ngsi-url"),
    ("no host", "https://:1026", None, "--ngsi-url"),
    ("a CA path with a line break", "https://127.0.0.1:1026", Path("/ca\n.pem"), "--ngsi-ca-file"),
]


@pytest.mark.parametrize(("url", "ca_file", "expected"), [c[1:] for c in REFUSED], ids=[c[0] for c in REFUSED])
def test_an_unusable_pair_is_refused_naming_the_option(url: str, ca_file: Path | None, expected: str) -> None:
    with pytest.raises(PlannerError) as caught:
        NgsiTrust(url, ca_file)
    assert expected in str(caught.value)


def test_contexts_verify_the_address_against_the_ca_file_or_the_system_store(plant_ca: ca.Ca) -> None:
    assert NgsiTrust("http://127.0.0.1:1026").context() is None
    for trust in (NgsiTrust("https://127.0.0.1:1026"), NgsiTrust("https://127.0.0.1:1026", plant_ca.cert_file)):
        context = trust.context()
        assert context is not None and context.verify_mode is ssl.CERT_REQUIRED and context.check_hostname
        assert context.minimum_version >= ssl.TLSVersion.TLSv1_2
    only = NgsiTrust("https://127.0.0.1:1026", plant_ca.cert_file).context()
    assert only is not None and len(only.get_ca_certs()) == 1  # the plant CA, nothing else


def test_a_ca_file_that_is_no_certificate_names_the_option(tmp_path: Path) -> None:
    (tmp_path / "ca.pem").write_text("not a certificate\n", encoding="utf-8")
    for missing_or_bad in (tmp_path / "ca.pem", tmp_path / "absent.pem"):
        with pytest.raises(PlannerError, match=f"{CA_OPTION} {missing_or_bad}: not a readable PEM"):
            NgsiTrust("https://127.0.0.1:1026", missing_or_bad).context()


def test_a_relative_ca_path_is_made_absolute(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    assert NgsiTrust("https://127.0.0.1:1026", Path("ca.pem")).ca_file == tmp_path / "ca.pem"


def test_the_plant_derives_https_and_the_plant_ca(plant_ca: ca.Ca) -> None:
    assert trust_of("127.0.0.3", 1026, False).flags() == ["--ngsi-url", "http://127.0.0.3:1026"]
    tls = trust_of("127.0.0.3", 1026, True, plant_ca.folder)
    assert tls.flags() == ["--ngsi-url", "https://127.0.0.3:1026", CA_OPTION, str(plant_ca.cert_file)]


def test_the_fleets_context_broker_in_the_plant_file_says_whether_it_speaks_tls(tmp_path: Path,
                                                                               plant_ca: ca.Ca) -> None:
    text = EXAMPLE.read_text(encoding="utf-8")
    assert plant_trust(load_plant([EXAMPLE]), plant_ca.folder).flags() == ["--ngsi-url", "http://127.0.0.3:1026"]
    (tmp_path / "tls.ttl").write_text(text.replace('pk:port 1026 .', 'pk:port 1026 ; pk:tls true .'), encoding="utf-8")
    assert plant_trust(load_plant([tmp_path / "tls.ttl"]), plant_ca.folder).flags() == [
        "--ngsi-url", "https://127.0.0.3:1026", CA_OPTION, str(plant_ca.cert_file)]
    (tmp_path / "none.ttl").write_text(text.replace('"ngsi-v2"', '"mosquitto"'), encoding="utf-8")
    with pytest.raises(PlannerError, match="no context broker for the fleet"):
        plant_trust(load_plant([tmp_path / "none.ttl"]))


def test_the_client_reads_and_writes_over_https_trusting_the_ca_file(broker: HttpServer, plant_ca: ca.Ca) -> None:
    trust = NgsiTrust(f"https://{HOST}:{broker.port}", plant_ca.cert_file)
    check_certificate(trust, trust.context())
    client = NgsiClient(trust.url, None, context=trust.context())
    client.write(ENTITY, {"sequence": 3})
    assert client.read(ENTITY) == {"id": ENTITY, "sequence": 3}


def test_the_task_publisher_writes_over_https_trusting_the_ca_file(broker: HttpServer, plant_ca: ca.Ca) -> None:
    task = build.build_task("j1-first-1", "j1", fleet.lotlan.parse(JOBS, "jobs.tl").task("first"), 1, SITE)
    trust = NgsiTrust(f"https://{HOST}:{broker.port}", plant_ca.cert_file)
    publisher = TaskPublisher(trust.url, None, context=trust.context())
    publisher.start()
    try:
        publisher.publish(task)
        wait_until(lambda: publisher.written, 10.0, what="the Task entity written over https")
    finally:
        publisher.stop()
    store = broker.app
    assert isinstance(store, Store) and store.entities["urn:ngsi-ld:Task:j1-first-1"]["job"] == "j1"


def test_the_event_subscription_is_made_over_https_trusting_the_ca_file(broker: HttpServer,
                                                                        plant_ca: ca.Ca) -> None:
    trust = NgsiTrust(f"https://{HOST}:{broker.port}", plant_ca.cert_file)
    for context, expected in ((trust.context(), None), (NgsiTrust(trust.url).context(), CA_OPTION)):
        events = NgsiEvents(trust.url, None, lambda *_: {}, "planner events", "t", context=context)
        events.notify_url = f"http://{HOST}:9/v1/ngsi/notify"
        if expected is None:
            assert events.ensure() == "0" * 24
        else:  # the system's store: the certificate is refused, and the error says what to give
            with pytest.raises(ContextBrokerError, match=f"not trusted.*{expected}"):
                events.ensure()


def test_the_system_store_refuses_the_plant_certificate_and_says_which_option(broker: HttpServer) -> None:
    trust = NgsiTrust(f"https://{HOST}:{broker.port}")
    with pytest.raises(PlannerError) as caught:
        check_certificate(trust, trust.context())
    assert f"{trust.url} shows a certificate that is not trusted" in str(caught.value)
    assert CA_OPTION in str(caught.value)
    with pytest.raises(PlannerError, match=f"certificate that is not trusted.*{CA_OPTION}"):
        NgsiClient(trust.url, None, context=trust.context()).write(ENTITY, {"sequence": 3})


def test_a_broker_that_does_not_answer_yet_is_no_certificate_problem() -> None:
    trust = NgsiTrust(f"https://{HOST}:{free_port()}")
    check_certificate(trust, trust.context(), timeout=2)  # logged; the planner retries later
    assert untrusted(ConnectionRefusedError()) is None


def _planner(tmp_path: Path, *ngsi: str) -> list[str]:
    (tmp_path / "jobs.tl").write_text(JOBS, encoding="utf-8")
    (tmp_path / "map.json").write_text(MAP, encoding="utf-8")
    (tmp_path / "manager.token").write_text("t\n", encoding="utf-8")
    return ["--plant", str(EXAMPLE), "--lotlan", str(tmp_path / "jobs.tl"), "--data-dir", str(tmp_path / "data"),
            "--manager-url", f"http://{HOST}:9", "--manager-token-file", str(tmp_path / "manager.token"),
            "--map", str(tmp_path / "map.json"), *ngsi]


def test_the_planner_exits_2_on_a_ca_file_beside_http(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(_planner(tmp_path, "--ngsi-url", f"http://{HOST}:9", CA_OPTION, str(tmp_path / "ca.pem")))
    err = capsys.readouterr().err
    assert code == 2 and f"{CA_OPTION} {tmp_path / 'ca.pem'}" in err and "https://" in err, err
    assert not (tmp_path / "data").exists()
    assert main(_planner(tmp_path, CA_OPTION, str(tmp_path / "ca.pem"))) == 2
    assert f"{CA_OPTION} needs --ngsi-url" in capsys.readouterr().err


def test_the_planner_exits_2_on_an_untrusted_certificate(broker: HttpServer, tmp_path: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    code = main(_planner(tmp_path, "--ngsi-url", f"https://{HOST}:{broker.port}"))
    err = capsys.readouterr().err
    assert code == 2 and "certificate that is not trusted" in err and CA_OPTION in err, err
    assert "Traceback" not in err and not (tmp_path / "data").exists()
