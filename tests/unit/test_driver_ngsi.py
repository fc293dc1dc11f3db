"""The NGSI-v2 context broker driver: command line, refusals, topics as entities, essence, health.

The server itself (engine.context_broker) is started for real by
tests/integration/test_context_broker_agent.py; here health is checked against plain HTTP servers
that answer /version in ways a context broker would not (and one that answers like Orion), so what
health accepts is pinned down without a broker process.
"""

from __future__ import annotations

import json
import socket
import sys
import threading
from collections.abc import Iterator
from dataclasses import replace
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from engine import netutil
from engine.drivers.base import Driver
from engine.drivers.ngsi import TOKEN_FILE_ENV, NgsiDriver
from engine.errors import ConfigValueError
from engine.model import (
    BridgeDirection,
    BridgeEnd,
    BridgeMechanism,
    BridgeRoute,
    BridgeSpec,
    BrokerSpec,
    ObservedTopic,
    TopicSpec,
)


def cb_spec(**changes) -> BrokerSpec:
    values = dict(id="cb", iri="https://example.org/plant#cb", name="Context broker", kind="ngsi-v2",
                  host="127.0.0.3", port=11026, allow_anonymous=False)
    return BrokerSpec(**{**values, **changes})


@pytest.fixture
def broker_dir(tmp_path: Path) -> Path:
    """``<state dir>/brokers/cb`` with the agent's token file at ``<state dir>/token``."""
    folder = tmp_path / "brokers" / "cb"
    folder.mkdir(parents=True)
    (tmp_path / "token").write_text("x" * 32 + "\n")
    return folder


def test_is_a_driver_registered_as_its_kind() -> None:
    driver = NgsiDriver()
    assert isinstance(driver, Driver)
    assert (driver.kind, driver.implicit_topics) == ("ngsi-v2", True)


def test_command_uses_the_agents_token_file(broker_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(TOKEN_FILE_ENV, raising=False)
    argv = NgsiDriver().command(cb_spec(), broker_dir)
    assert argv == [sys.executable, "-m", "engine.context_broker", "--host", "127.0.0.3", "--port", "11026",
                    "--data-dir", str(broker_dir / "data"), "--log-file", str(broker_dir / "logs" / "ngsi-v2.log"),
                    "--token-file", str(broker_dir.parent.parent / "token"),
                    "--principals", str(broker_dir / "principals.json")]  # closed by default: reads need a token


def test_an_agent_with_another_token_file_passes_it_in_the_environment(
        broker_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    other = tmp_path / "elsewhere" / "agent.token"
    other.parent.mkdir()
    other.write_text("y" * 32)
    monkeypatch.setenv(TOKEN_FILE_ENV, str(other))
    assert NgsiDriver().command(cb_spec(), broker_dir)[-4:-2] == ["--token-file", str(other)]


def test_allow_anonymous_opens_writes_and_needs_no_token(tmp_path: Path) -> None:
    folder = tmp_path / "brokers" / "cb"  # no token file anywhere
    argv = NgsiDriver().command(cb_spec(allow_anonymous=True), folder)
    assert argv[-1] == "--open" and "--token-file" not in argv


def test_a_missing_token_file_is_refused_naming_what_to_do(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv(TOKEN_FILE_ENV, raising=False)
    with pytest.raises(ConfigValueError) as info:
        NgsiDriver().command(cb_spec(), tmp_path / "brokers" / "cb")
    assert info.value.field == "token_file" and "pk:allowAnonymous" in str(info.value)


def test_prepare_makes_the_data_folder_and_a_closed_broker_gets_an_empty_principals_file(broker_dir: Path) -> None:
    driver = NgsiDriver()
    driver.prepare(cb_spec(), broker_dir)
    driver.prepare(cb_spec(), broker_dir)  # idempotent
    assert (broker_dir / "data").is_dir()
    assert json.loads(driver.render_config(cb_spec(), broker_dir)["principals.json"]) == {"principals": []}
    assert driver.render_config(cb_spec(allow_anonymous=True), broker_dir) == {}  # open: nothing rendered
    (broker_dir / "principals.json").write_text("{}")
    driver.prepare(cb_spec(allow_anonymous=True), broker_dir)
    assert not (broker_dir / "principals.json").exists()  # an opened broker loses its file


def test_bridges_are_not_native() -> None:
    bridge = BridgeSpec(BridgeEnd("m", "mosquitto", "127.0.0.2", 1883), BridgeEnd("cb", "ngsi-v2", "127.0.0.3", 1026),
                        BridgeMechanism.NGSI, (BridgeRoute("t", BridgeDirection.OUT, 1, "mqtt-topic", "urn:x", "Thing"),))
    with pytest.raises(ConfigValueError) as info:
        NgsiDriver().render_config(cb_spec(), Path("/state/brokers/cb"), (bridge,))
    assert info.value.field == "bridges"


@pytest.mark.parametrize(("changes", "field"), [
    ({"port": 0}, "port"),
    ({"port": "1026"}, "port"),
    ({"host": "orion.local"}, "host"),
    ({"host": "127.0.0.1\n--open"}, "host"),
    ({"allow_anonymous": "yes"}, "allow_anonymous"),
    ({"persist_every": 1}, "persist_every"),
    ({"closed_kafkas": ("127.0.0.4",)}, "closed_kafkas[0]"),
    ({"closed_kafkas": ("127.0.0.4:9092", "kafka.local:9092")}, "closed_kafkas[1]"),
    ({"closed_kafkas": ("127.0.0.4:9092\n--open",)}, "closed_kafkas[0]"),
    ({"closed_kafkas": ("::1:9092",)}, "closed_kafkas[0]"),
    ({"tls_kafkas": ("127.0.0.4:9092\n--open",)}, "tls_kafkas[0]"),
])
def test_bad_broker_values_are_refused(changes: dict, field: str) -> None:
    with pytest.raises(ConfigValueError) as info:
        NgsiDriver().validate(cb_spec(**changes))
    assert info.value.field == field


def test_an_unsafe_broker_folder_is_refused() -> None:
    with pytest.raises(ConfigValueError):
        NgsiDriver().command(cb_spec(allow_anonymous=True), Path("relative/brokers/cb"))
    with pytest.raises(ConfigValueError):
        NgsiDriver().command(cb_spec(allow_anonymous=True), Path("/state/bro\nkers/cb"))


# --- topics are entities --------------------------------------------------------------------

def topic(**changes) -> TopicSpec:
    values = dict(broker_id="cb", name="agv/1/status", iri="urn:t",
                  entity_id="urn:ngsi-ld:Thing:agv:1:status", entity_type="Thing")
    return TopicSpec(**{**values, **changes})


def test_ensure_topic_checks_and_returns_the_entity() -> None:
    assert NgsiDriver().ensure_topic(cb_spec(), topic()) == ObservedTopic(
        "agv/1/status", entity_id="urn:ngsi-ld:Thing:agv:1:status", entity_type="Thing")
    NgsiDriver().delete_topic(cb_spec(), "agv/1/status")  # nothing to do, no error
    assert NgsiDriver().observe_topics(cb_spec()) == []


@pytest.mark.parametrize(("changes", "field"), [
    ({"entity_id": None}, "entity_id"),
    ({"entity_type": None}, "entity_type"),
    ({"entity_id": "urn:agv 1"}, "entity_id"),
    ({"entity_id": "urn:agv/1"}, "entity_id"),
    ({"entity_id": "a" * 257}, "entity_id"),
    ({"entity_type": "AGV;drop"}, "entity_type"),
    ({"entity_type": "Fahrzeug\u00e4"}, "entity_type"),
    ({"qos": 1}, "qos"),
    ({"partitions": 3}, "partitions"),
    ({"name": "a\nb"}, "name"),
])
def test_bad_topics_are_refused_naming_the_field(changes: dict, field: str) -> None:
    with pytest.raises(ConfigValueError) as info:
        NgsiDriver().ensure_topic(cb_spec(), topic(**changes))
    assert info.value.field == field


def test_the_longest_entity_id_is_accepted() -> None:
    NgsiDriver().ensure_topic(cb_spec(), topic(entity_id="e" * 256))


def test_the_plants_closed_kafkas_are_on_the_command_line(broker_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The context broker's kafka:// notifications log in there (and nowhere else) as plantkg."""
    monkeypatch.delenv(TOKEN_FILE_ENV, raising=False)
    spec = cb_spec(closed_kafkas=("127.0.0.4:9092", "[::1]:9093"))
    argv = NgsiDriver().command(spec, broker_dir)
    at = argv.index("--closed-kafka")
    assert argv[at:at + 4] == ["--closed-kafka", "127.0.0.4:9092", "--closed-kafka", "[::1]:9093"]
    assert argv.count("--closed-kafka") == 2
    assert "--closed-kafka" in NgsiDriver().command(replace(spec, allow_anonymous=True), broker_dir)
    assert "--closed-kafka" not in NgsiDriver().command(cb_spec(), broker_dir)


def test_the_plants_tls_kafkas_are_on_the_command_line(broker_dir: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The context broker's kafka:// notifications speak TLS there, trusting the plant CA."""
    monkeypatch.delenv(TOKEN_FILE_ENV, raising=False)
    argv = NgsiDriver().command(cb_spec(closed_kafkas=("127.0.0.4:9092",), tls_kafkas=("127.0.0.4:9092",)), broker_dir)
    at = argv.index("--tls-kafka")
    assert argv[at:at + 2] == ["--tls-kafka", "127.0.0.4:9092"] and argv.count("--tls-kafka") == 1
    assert "--tls-kafka" not in NgsiDriver().command(cb_spec(closed_kafkas=("127.0.0.4:9092",)), broker_dir)


# --- essence --------------------------------------------------------------------------------

def test_essence_is_the_listener_and_the_write_policy() -> None:
    driver = NgsiDriver()
    spec = cb_spec()
    assert driver.essence(spec) == {"kind": "ngsi-v2", "host": "127.0.0.3", "port": 11026, "allow_anonymous": False}
    assert driver.essence(cb_spec(name="Other", iri="urn:o")) == driver.essence(spec)
    assert driver.essence(cb_spec(allow_anonymous=None)) == driver.essence(spec)  # unset: token needed
    assert driver.essence(cb_spec(allow_anonymous=True)) != driver.essence(spec)
    assert driver.essence(cb_spec(port=11027)) != driver.essence(spec)
    closed = cb_spec(closed_kafkas=("127.0.0.4:9092",))  # on the command line: a change restarts it
    assert driver.essence(closed) == {**driver.essence(spec), "closed_kafkas": ["127.0.0.4:9092"]}
    tls = cb_spec(tls_kafkas=("127.0.0.4:9092",))
    assert driver.essence(tls) == {**driver.essence(spec), "tls_kafkas": ["127.0.0.4:9092"]}


# --- health ---------------------------------------------------------------------------------

def _server(status: int, body: bytes) -> ThreadingHTTPServer:
    class Handler(BaseHTTPRequestHandler):
        def do_GET(self) -> None:  # noqa: N802 - http.server's name
            self.send_response(status if self.path == "/version" else 404)
            self.send_header("Content-Type", "application/json")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)

        def log_message(self, *args: object) -> None:
            pass

    return ThreadingHTTPServer(("127.0.0.1", 0), Handler)


@pytest.fixture
def http_server(request: pytest.FixtureRequest) -> Iterator[int]:
    status, body = request.param
    server = _server(status, body)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield server.server_address[1]
    finally:
        server.shutdown()
        server.server_close()
        thread.join(5)


ORION_VERSION = json.dumps({"orion": {"version": "3.10.1", "uptime": "0 d, 0 h, 0 m, 1 s"}}).encode()


@pytest.mark.parametrize(("http_server", "healthy"), [
    ((200, ORION_VERSION), True),
    ((200, b'{"version": "1.0"}'), False),        # some other JSON service
    ((200, b'{"orion": "3.10.1"}'), False),       # orion must be an object
    ((200, b"<html>it works</html>"), False),     # a web server
    ((503, ORION_VERSION), False),                 # up, but says it is not ready
], indirect=["http_server"])
def test_health_is_a_version_answer_with_an_orion_object(http_server: int, healthy: bool) -> None:
    assert NgsiDriver().health(cb_spec(host="127.0.0.1", port=http_server), 1.0) is healthy


def test_nothing_listening_or_a_silent_listener_is_not_healthy() -> None:
    assert NgsiDriver().health(cb_spec(host="127.0.0.1", port=netutil.free_port()), 0.5) is False
    with socket.create_server(("127.0.0.1", 0)) as server:  # accepts, never answers
        assert NgsiDriver().health(cb_spec(host="127.0.0.1", port=server.getsockname()[1]), 0.3) is False


# --- pk:tls: HTTPS only, a plant-CA certificate for its address ------------------------------

def _version_app(environ: dict, start_response) -> list[bytes]:
    body = json.dumps({"orion": {"version": "3.10.1"}}).encode()
    start_response("200 OK", [("Content-Type", "application/json"), ("Content-Length", str(len(body)))])
    return [body]


def _https_server(tmp_path: Path, authority, port: int):
    """A real context-broker HTTP server (engine.context_broker.http_server) answering /version
    over TLS with a certificate of ``authority`` for 127.0.0.1, running until the block ends."""
    from engine.context_broker.http_server import HttpServer  # noqa: PLC0415 - the server, not the driver
    from engine.security import ca, https  # noqa: PLC0415
    from tests.unit.context_broker.test_http_server import serving  # noqa: PLC0415
    cert, key = ca.issue_server_cert(authority, ("127.0.0.1",), name="test")
    (tmp_path / "c.pem").write_bytes(cert)
    (tmp_path / "k.pem").write_bytes(key)
    return serving(HttpServer(_version_app, "127.0.0.1", port, 1,
                              ssl_context=https.server_context(tmp_path / "c.pem", tmp_path / "k.pem")))


def test_tls_renders_a_plant_ca_certificate_for_its_address_kept_while_current(broker_dir: Path) -> None:
    from cryptography import x509  # noqa: PLC0415
    from engine.security import ca  # noqa: PLC0415
    driver, spec = NgsiDriver(), cb_spec(tls=True)
    files = driver.render_config(spec, broker_dir)
    assert {"tls-cert.pem", "tls-key.pem", "principals.json"} <= set(files)
    cert = x509.load_pem_x509_certificate(files["tls-cert.pem"].encode())
    assert ca.needs_new_cert(files["tls-cert.pem"].encode(), ca.load_ca(ca.ca_dir()), ("127.0.0.3",)) is None
    assert cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value.get_values_for_type(
        x509.IPAddress)[0].exploded == "127.0.0.3"
    assert driver.tls_renewal(spec, broker_dir) == "none yet"
    for name, text in files.items():
        (broker_dir / name).write_text(text)
    assert driver.render_config(spec, broker_dir) == files  # the same files: no restart
    assert driver.tls_renewal(spec, broker_dir) is None
    assert driver.tls_renewal(replace(spec, host="127.0.0.4"), broker_dir) == "for other addresses"
    argv = driver.command(spec, broker_dir)
    at = argv.index("--tls-cert")
    assert argv[at:at + 4] == ["--tls-cert", str(broker_dir / "tls-cert.pem"),
                               "--tls-key", str(broker_dir / "tls-key.pem")]
    assert set(driver.render_config(cb_spec(tls=True, allow_anonymous=True), broker_dir)) == {
        "tls-cert.pem", "tls-key.pem"}  # an open one too


def test_a_plain_broker_renders_no_tls_and_leaves_no_key(broker_dir: Path) -> None:
    driver = NgsiDriver()
    (broker_dir / "tls-key.pem").write_text("old key")
    assert "--tls-cert" not in driver.command(cb_spec(), broker_dir)
    assert not {"tls-cert.pem", "tls-key.pem"} & set(driver.render_config(cb_spec(), broker_dir))
    driver.prepare(cb_spec(), broker_dir)
    assert not (broker_dir / "tls-key.pem").exists()
    assert driver.tls_renewal(cb_spec(), broker_dir) is None
    assert "tls" not in driver.essence(cb_spec())  # a plain broker's essence stays as it was
    assert driver.essence(cb_spec(tls=True))["tls"] is True


def test_health_of_a_tls_broker_speaks_https_and_trusts_the_plant_ca_only(tmp_path: Path) -> None:
    from engine.security import ca  # noqa: PLC0415
    driver, port = NgsiDriver(), netutil.free_port("127.0.0.1")
    spec = cb_spec(host="127.0.0.1", port=port, tls=True)
    with _https_server(tmp_path, ca.load_or_create_ca(ca.ca_dir()), port):
        assert driver.health(spec, 2.0) is True
        assert driver.health(replace(spec, tls=False), 1.0) is False  # plain HTTP gets no answer
    other_port = netutil.free_port("127.0.0.1")
    with _https_server(tmp_path, ca.load_or_create_ca(tmp_path / "other-ca"), other_port):
        assert driver.health(replace(spec, port=other_port), 1.0) is False  # another CA's certificate
