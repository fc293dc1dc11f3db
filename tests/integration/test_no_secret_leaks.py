"""A secret is never shown or stored where it does not belong (issue 13), grepped for.

A plant of two closed Mosquittos on two "machines", the first speaking TLS, bridged by rule R1: a
robot publishes its pose on the first (its password in a ``file:`` secret), an HMI reads it on the
second (its password in the agents' environment). The agents serve HTTPS. Every user-facing
surface is then searched for the two passwords and for plantkg's own principals' passwords
(derived from the principal key):

- the output of ``validate``, ``plan`` (text and JSON), ``apply``, ``status`` (text and JSON),
  ``check --probe``, ``query --live`` and ``destroy``;
- every log: the agents', the brokers', the bridge's;
- every file in the agents' state dirs, with two exceptions that must hold a principal's password
  and are 0600: the carrying broker's ``mosquitto.conf`` (the bridge's ``remote_password``: Mosquitto
  reads it there). The users files hold hashes only;
- the dashboard's pages and JSON API, and the SPARQL endpoint's answer to "every quad of every
  graph", live state included.
"""

from __future__ import annotations

import json
import secrets
import stat
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from engine import netutil
from engine.cli import main
from engine.security import principal_key, principals
from engine.web.app import WebConfig, create_app
from engine.web.plant_state import PlantState
from tests.integration.agents import AgentFleet, start_agents

pytestmark = pytest.mark.integration

A_HOST, B_HOST = "127.0.0.2", "127.0.0.3"
HMI_ENV = "PLANTKG_TEST_LEAK_HMI_PW"
TOKEN = "leak-test-web-token-0123456789"

PLANT = """\
@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <http://example.org/leak#> .
:a a pk:Broker ; pk:id "cell" ; pk:name "cell broker" ; pk:brokerType "mosquitto" ;
    pk:ip "{a_host}" ; pk:port {a_port} ; pk:tls true ; pk:hasTopic :pose .
:b a pk:Broker ; pk:id "line" ; pk:name "line broker" ; pk:brokerType "mosquitto" ;
    pk:ip "{b_host}" ; pk:port {b_port} ; pk:hasTopic :pose .
:pose a pk:Topic ; pk:id "pose" ; pk:name "cell/robot/pose" ; pk:qos 1 .
:robot a pk:Resource ; pk:id "robot1" ; pk:name "Robot" ; pk:sendsTo :a ; pk:publishes :pose ;
    pk:secretRef "file:{robot_file}" .
:hmi a pk:Resource ; pk:id "hmi" ; pk:name "HMI" ; pk:sendsTo :b ; pk:subscribes :pose ;
    pk:secretRef "env:{hmi_env}" .
"""


@dataclass
class Leaky:
    fleet: AgentFleet
    plant: Path
    secrets: dict[str, str]       # what must appear nowhere
    principal: dict[str, str]     # plantkg's principals' passwords: only where they must be
    outputs: dict[str, str]


def _run(capsys: pytest.CaptureFixture[str], *args: object) -> tuple[int, str]:
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out + out.err


@pytest.fixture(scope="module")
def leaky(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Leaky]:
    tmp = tmp_path_factory.mktemp("leaks")
    robot, hmi = f"ROBOT-{secrets.token_hex(12)}", f"HMI-{secrets.token_hex(12)}"
    robot_file = tmp / "secrets" / "robot1"
    robot_file.parent.mkdir()
    robot_file.write_text(robot + "\n")
    robot_file.chmod(0o600)
    with pytest.MonkeyPatch.context() as env:
        env.setenv(HMI_ENV, hmi)
        fleet = start_agents([A_HOST, B_HOST], tmp / "agents", tls=True)
    plant = tmp / "plant.ttl"
    plant.write_text(PLANT.format(a_host=A_HOST, b_host=B_HOST, a_port=netutil.free_port(A_HOST),
                                  b_port=netutil.free_port(B_HOST), robot_file=robot_file, hmi_env=HMI_ENV))
    names = (principals.AGENT, principals.OBSERVER, principals.CHECK, principals.bridge_principal("cell", "line"))
    try:
        yield Leaky(fleet, plant, {"robot1": robot, "hmi": hmi},
                    {n: principal_key.password_for(n) for n in names}, {})
    finally:
        fleet.stop()


def test_command_outputs_show_no_secret(leaky: Leaky, capsys: pytest.CaptureFixture[str]) -> None:
    agents = ["--agents", leaky.fleet.agents_file]
    commands = {
        "validate": ["validate", leaky.plant],
        "plan": ["plan", leaky.plant, *agents],
        "plan --format json": ["plan", leaky.plant, *agents, "--format", "json"],
        "apply": ["apply", leaky.plant, *agents, "--yes"],
        "status": ["status", leaky.plant, *agents],
        "status --format json": ["status", leaky.plant, *agents, "--format", "json"],
        "check --probe": ["check", leaky.plant, *agents, "--probe"],
        "query --live": ["query", leaky.plant, "--live", *agents,
                         "SELECT ?s ?p ?o WHERE { ?s ?p ?o }", "--format", "csv"],
    }
    for label, args in commands.items():
        code, out = _run(capsys, *args)
        leaky.outputs[label] = out
        assert code == 0 or label == "check --probe", (label, out[-2000:])
    # the plan shows who may do what and where each password is, never the password
    assert f"env:{HMI_ENV}" in leaky.outputs["plan"] and "secrets/robot1" in leaky.outputs["plan"]
    assert "plantkg.bridge.cell.line" in leaky.outputs["plan --format json"]
    for label, out in leaky.outputs.items():
        for secret in (*leaky.secrets.values(), *leaky.principal.values()):
            assert secret not in out, label


def test_no_log_and_no_state_file_holds_a_secret(leaky: Leaky) -> None:
    carried_conf = leaky.fleet.agents[A_HOST].state_dir / "brokers" / "cell" / "mosquitto.conf"
    bridge_password = leaky.principal[principals.bridge_principal("cell", "line")]
    assert bridge_password in carried_conf.read_text()   # where Mosquitto must read it...
    assert stat.S_IMODE(carried_conf.stat().st_mode) == 0o600  # ...readable by the agent's user only
    searched = 0
    for root in {a.state_dir.parent for a in leaky.fleet.agents.values()}:  # state dirs and logs
        for path in root.rglob("*"):
            if not path.is_file():
                continue
            data = path.read_bytes()
            searched += 1
            for secret in leaky.secrets.values():
                assert secret.encode() not in data, path
            for name, password in leaky.principal.items():
                if password.encode() in data:
                    assert path == carried_conf and password == bridge_password, (path, name)
    assert searched > 20


def test_the_dashboard_and_the_sparql_endpoint_show_no_secret(leaky: Leaky) -> None:
    state = PlantState([str(leaky.plant)], leaky.fleet.agents_file)
    state.reload()
    app = create_app(WebConfig(state=state, token=TOKEN))
    try:
        client = app.test_client()
        bodies = {}
        for url in ("/", "/plan", "/validation", "/query", "/api/status", "/api/plan", "/api/validation",
                    "/api/rates", "/api/openapi.json"):
            response = client.get(url)
            assert response.status_code == 200, url
            bodies[url] = response.get_data(as_text=True)
        response = client.post("/sparql", data={"query": "SELECT ?g ?s ?p ?o WHERE { { ?s ?p ?o } UNION "
                                                         "{ GRAPH ?g { ?s ?p ?o } } }"},
                               headers={"Accept": "application/sparql-results+json"})
        assert response.status_code == 200
        answer = response.get_data(as_text=True)
        assert len(json.loads(answer)["results"]["bindings"]) > 100  # the plant, inferred and live graphs
        bodies["/sparql"] = answer
        assert HMI_ENV in answer  # the reference is there...
        for url, body in bodies.items():
            for secret in (*leaky.secrets.values(), *leaky.principal.values()):
                assert secret not in body, url  # ...the secrets are not
    finally:
        app.extensions["plantkg_sparql"].close()  # its query worker processes
        state.close()


def test_destroy_shows_no_secret(leaky: Leaky, capsys: pytest.CaptureFixture[str]) -> None:
    code, out = _run(capsys, "destroy", leaky.plant, "--agents", leaky.fleet.agents_file, "--yes")
    assert code == 0, out
    for secret in (*leaky.secrets.values(), *leaky.principal.values()):
        assert secret not in out
