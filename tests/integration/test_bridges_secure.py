"""A closed, TLS-only plant end to end: two Mosquittos bridged, agents serving HTTPS (issue 13).

Two Mosquitto brokers on two "machines" (127.0.0.2, 127.0.0.3), each with ``pk:tls true`` and no
``pk:allowAnonymous`` (closed by default); a robot publishes the pose on src, an HMI reads it on
dst, each with a password its ``pk:secretRef`` names (throwaway, in the agents' environment), so
rule R1 derives the bridge src -> dst. The agents serve their API over HTTPS with certificates of
the test run's plant CA, and ``plantkg apply`` verifies them against it. What is checked:

- 10,000 QoS 1 messages cross the bridge, none missing, first occurrences in order, with TLS and
  passwords on every hop (robot -> src, the bridge logging in to dst as its principal, dst -> HMI);
- every broker refuses an anonymous client, a client that does not speak TLS, and a TLS client
  that does not trust the plant CA; Debian's ``mosquitto_pub``/``mosquitto_sub`` with ``--cafile``
  do exactly what the robot's and the HMI's rights allow;
- the agent API refuses a client without the plant CA (and plain HTTP);
- the brokers' key files are 0600, and no rendered file holds a plant secret.
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import signal
import shutil
import ssl
import stat
import subprocess
import threading
import urllib.request
import uuid
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from paho.mqtt import client as mqtt
from paho.mqtt.enums import CallbackAPIVersion

from engine import netutil, process
from engine.agent.client import AgentClient
from engine.cli import main
from engine.errors import PermanentDispatchError
from engine.model import BridgeStatus
from engine.security import ca
from tests.integration.agents import Deployment, deployment
from tests.integration.test_bridges import check_complete

pytestmark = pytest.mark.integration

SRC_HOST, DST_HOST = "127.0.0.2", "127.0.0.3"
POSE, CMD = "cell/robot/pose", "cell/robot/cmd"
MESSAGES = 10_000
PERSIST_EVERY = 10    # dst's pk:persistEvery: the kill test's bound on unsaved changes (as test_bridges)
ROBOT_ENV, HMI_ENV = "PLANTKG_TEST_TLS_ROBOT_PW", "PLANTKG_TEST_TLS_HMI_PW"

PLANT = """\
@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <http://example.org/secure-bridge#> .
:src a pk:Broker ; pk:id "src" ; pk:name "cell broker" ; pk:brokerType "mosquitto" ;
    pk:ip "{src_host}" ; pk:port {src_port} ; pk:tls true ; pk:hasTopic :pose , :cmd .
:dst a pk:Broker ; pk:id "dst" ; pk:name "line broker" ; pk:brokerType "mosquitto" ;
    pk:ip "{dst_host}" ; pk:port {dst_port} ; pk:tls true ; pk:persistEvery {persist_every} ; pk:hasTopic :pose .
:pose a pk:Topic ; pk:id "pose" ; pk:name "{pose}" ; pk:qos 1 .
:cmd a pk:Topic ; pk:id "cmd" ; pk:name "{cmd}" ; pk:qos 1 .
:robot a pk:Resource ; pk:id "robot1" ; pk:name "Robot" ; pk:sendsTo :src ; pk:publishes :pose ;
    pk:subscribes :cmd ; pk:secretRef "env:{robot_env}" .
:hmi a pk:Resource ; pk:id "hmi" ; pk:name "HMI" ; pk:sendsTo :dst ; pk:subscribes :pose ;
    pk:secretRef "env:{hmi_env}" .
"""


@dataclass(frozen=True)
class Secure:
    deployed: Deployment
    passwords: dict[str, str]


@pytest.fixture(scope="module")
def secure(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Secure]:
    passwords = {"robot1": secrets.token_urlsafe(16), "hmi": secrets.token_urlsafe(16)}

    def plant(ports: dict[str, int]) -> str:
        return PLANT.format(src_host=SRC_HOST, dst_host=DST_HOST, src_port=ports["src"], dst_port=ports["dst"],
                            pose=POSE, cmd=CMD, robot_env=ROBOT_ENV, hmi_env=HMI_ENV,
                            persist_every=PERSIST_EVERY)

    with deployment(tmp_path_factory.mktemp("secure-bridge"), {"src": SRC_HOST, "dst": DST_HOST}, plant, tls=True,
                    agent_env={ROBOT_ENV: passwords["robot1"], HMI_ENV: passwords["hmi"]}) as made:
        assert all(a.url.startswith("https://") for a in made.fleet.agents.values())
        yield Secure(made, passwords)


def client(host: str, port: int, user: str | None, password: str | None, *, tls: str = "plant-ca",
           inflight: int | None = None, **kwargs: object) -> tuple[mqtt.Client, list[str]]:
    """A paho client that connected (or was refused); returns it and the CONNACK reasons (an
    empty list: the connection itself failed). ``tls``: "plant-ca", "system" (the system's
    trust store only) or "none" (plain TCP)."""
    c = mqtt.Client(CallbackAPIVersion.VERSION2, client_id=f"it-{uuid.uuid4().hex[:8]}", **kwargs)
    if tls == "plant-ca":
        c.tls_set(ca_certs=str(ca.ca_cert_file()))
    elif tls == "system":
        c.tls_set()
    if user is not None:
        c.username_pw_set(user, password)
    if inflight is not None:
        c.max_inflight_messages_set(inflight)
        c.max_queued_messages_set(0)
    answers: list[str] = []
    c.on_connect = lambda _c, _u, _f, reason, _p: answers.append(str(reason))
    try:
        c.connect(host, port, keepalive=10)
    except (OSError, ssl.SSLError):
        return c, answers
    c.loop_start()
    try:  # a listener that cannot read the CONNECT (plain MQTT at TLS) never answers it
        process.wait_until(lambda: answers, 10.0 if tls != "none" else 3.0, what="a CONNACK")
    except process.WaitTimeoutError:
        pass
    return c, answers


def hmi_and_robot(secure: Secure) -> tuple[mqtt.Client, list[int], mqtt.Client]:
    """The HMI subscribed to the pose on dst (a persistent session, logged in, over TLS), the
    integers it receives, and the robot's publisher on src (1000 in flight)."""
    got: list[int] = []
    subscribed = threading.Event()
    sink, answers = client(DST_HOST, secure.deployed.ports["dst"], "hmi", secure.passwords["hmi"], clean_session=False)
    assert answers == ["Success"]
    sink.reconnect_delay_set(0.1, 1)
    sink.on_subscribe = lambda *_: subscribed.set()
    sink.on_message = lambda _c, _u, msg: got.append(int(msg.payload))
    sink.subscribe(POSE, qos=1)
    assert subscribed.wait(10)
    pub, answers = client(SRC_HOST, secure.deployed.ports["src"], "robot1", secure.passwords["robot1"], inflight=1000)
    assert answers == ["Success"]
    return sink, got, pub


def close(c: mqtt.Client) -> None:
    c.loop_stop()
    c.disconnect()


def test_10k_messages_cross_the_bridge_with_tls_and_passwords(secure: Secure) -> None:
    src = secure.deployed.fleet.client(SRC_HOST)
    process.wait_until(lambda: [b.status for b in src.list_bridges()] == [BridgeStatus.RUNNING], 30, 0.1,
                       what="the bridge to report running (its state read over TLS as plantkg.agent)")
    sink, got, pub = hmi_and_robot(secure)
    try:
        infos = [pub.publish(POSE, str(n).encode(), qos=1) for n in range(MESSAGES)]
        for info in infos:
            info.wait_for_publish(timeout=60)
        process.wait_until(lambda: len(set(got)) >= MESSAGES, 120, 0.05,
                           what=f"{MESSAGES} messages through the TLS bridge")
        duplicates = check_complete(list(got), range(MESSAGES))
        print(f"\n{MESSAGES} messages through the closed TLS bridge, {duplicates} duplicates")
    finally:
        close(pub)
        close(sink)


def test_a_closed_target_killed_mid_stream_loses_at_most_its_unsaved_changes(secure: Secure) -> None:
    """SIGKILL dst while 10,000 messages cross the bridge: its agent restarts it and the HMI (a
    persistent session, logged in) gets every message but dst's unsaved changes. The users file
    (dynamic security plugin) checks a session restored from dst's database by its user name, so
    what the bridge delivers before the HMI has reconnected is kept for it (Mosquitto's ACL file
    denied it: docs/security.md)."""
    allowed = PERSIST_EVERY  # dst saves after every PERSIST_EVERY changes (the default saves by time)
    dst = secure.deployed.fleet.client(DST_HOST)
    before = dst.get_broker("dst")
    assert before is not None and before.pid
    sink, got, pub = hmi_and_robot(secure)

    def kill_when_a_third_arrived() -> None:
        process.wait_until(lambda: len(set(got)) >= MESSAGES // 3, 120, 0.005, what="a third of the messages")
        os.kill(before.pid, signal.SIGKILL)

    killer = threading.Thread(target=kill_when_a_third_arrived)
    killer.start()
    try:
        infos = [pub.publish(POSE, str(MESSAGES + n).encode(), qos=1) for n in range(MESSAGES)]
        for info in infos:
            info.wait_for_publish(timeout=120)
        killer.join(120)
        process.wait_until(lambda: (b := dst.get_broker("dst")) is not None and b.restarts == before.restarts + 1
                           and b.status.value == "running", 60, 0.1, what="dst restarted by its agent")
        sent = set(range(MESSAGES, 2 * MESSAGES))
        with contextlib.suppress(process.WaitTimeoutError):
            process.wait_until(lambda: len(set(got) & sent) >= MESSAGES, 60, 0.1, what="every message")
        missing = sorted(sent - set(got))
        print(f"\nclosed TLS target SIGKILLed: missing {len(missing)} (first {missing[:10]})")
        assert len(missing) <= allowed, missing[:50]
    finally:
        close(pub)
        close(sink)


@pytest.mark.parametrize("host", [SRC_HOST, DST_HOST])
def test_every_broker_refuses_anonymous_plain_and_untrusting_clients(secure: Secure, host: str) -> None:
    port = secure.deployed.ports["src" if host == SRC_HOST else "dst"]
    anonymous, answers = client(host, port, None, None)
    assert answers == ["Not authorized"], answers
    close(anonymous)
    plain, answers = client(host, port, "robot1", secure.passwords["robot1"], tls="none")
    assert "Success" not in answers  # the listener speaks TLS only: no CONNACK for plain MQTT
    close(plain)
    with pytest.raises(ssl.SSLCertVerificationError):
        bare = mqtt.Client(CallbackAPIVersion.VERSION2)
        bare.tls_set()  # the system's trust store: the plant CA is not in it
        bare.connect(host, port)


needs_clients = pytest.mark.skipif(shutil.which("mosquitto_pub") is None,
                                   reason="mosquitto-clients not installed (scripts/setup.sh)")


@needs_clients
def test_mosquitto_clients_over_tls_do_exactly_what_the_rights_allow(secure: Secure) -> None:
    """Debian's clients with --cafile: the robot writes the pose and reads the command on src,
    and may not read the pose (nothing arrives); anonymous is refused at CONNECT."""
    def cli(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(list(args), capture_output=True, text=True, timeout=30)

    common = ["-h", SRC_HOST, "-p", str(secure.deployed.ports["src"]), "--cafile", str(ca.ca_cert_file()),
              "-V", "mqttv311"]
    robot = ["-u", "robot1", "-P", secure.passwords["robot1"]]
    published = cli("mosquitto_pub", *common, *robot, "-q", "1", "-r", "-t", POSE, "-m", "from-cli")
    assert published.returncode == 0, published.stderr
    denied = cli("mosquitto_sub", *common, *robot, "-t", POSE, "-C", "1", "-W", "2")
    assert denied.returncode != 0 and "from-cli" not in denied.stdout, (denied.stdout, denied.stderr)
    anonymous = cli("mosquitto_pub", *common, "-t", POSE, "-m", "anon")
    assert anonymous.returncode != 0 and "not authori" in anonymous.stderr.lower(), anonymous.stderr
    no_ca = cli("mosquitto_pub", "-h", SRC_HOST, "-p", str(secure.deployed.ports["src"]), *robot, "-t", POSE,
                "-m", "plain")
    assert no_ca.returncode != 0


def test_the_agent_api_refuses_a_client_without_the_plant_ca(secure: Secure, tmp_path: Path) -> None:
    agent = secure.deployed.fleet.agents[SRC_HOST]
    assert AgentClient(agent.url, agent.token).health()["status"] == "ok"  # the plant CA: trusted
    other = ca.load_or_create_ca(tmp_path / "other-ca")                    # another CA: refused
    with pytest.raises(PermanentDispatchError, match="TLS certificate is not trusted"):
        AgentClient(agent.url, agent.token, ca_file=other.cert_file).health()
    with pytest.raises(urllib.error.URLError) as info:  # the system's trust store: refused
        urllib.request.urlopen(f"{agent.url}/v1/health", timeout=10,
                               context=ssl.create_default_context())
    assert isinstance(info.value.reason, ssl.SSLCertVerificationError)
    plain = agent.url.replace("https://", "http://")
    with pytest.raises((urllib.error.URLError, ConnectionError, OSError)):
        urllib.request.urlopen(f"{plain}/v1/health", timeout=10)


def test_status_says_each_broker_is_closed_and_speaks_tls(secure: Secure,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    capsys.readouterr()
    assert main(["status", str(secure.deployed.plant), "--agents", str(secure.deployed.fleet.agents_file), "--format", "json"]) == 0
    brokers = {b["id"]: b for b in json.loads(capsys.readouterr().out)["brokers"]}
    assert {k: (b["anonymous"], b["tls"]) for k, b in brokers.items()} == {"src": (False, True), "dst": (False, True)}
    assert brokers["dst"]["users"] == 2  # the HMI and the bridge's principal
    assert main(["status", str(secure.deployed.plant), "--agents", str(secure.deployed.fleet.agents_file)]) == 0
    table = capsys.readouterr().out
    assert "users (1), TLS" in table and "users (2), TLS" in table


def test_apply_renews_a_certificate_that_is_due(secure: Secure, capsys: pytest.CaptureFixture[str]) -> None:
    """The agent reports a broker certificate due for renewal (here: for another address), the
    plan shows it without any key, and apply has the agent issue a new one and restart the broker."""
    folder = secure.deployed.fleet.agents[SRC_HOST].state_dir / "brokers" / "src"
    cert, key = ca.issue_server_cert(ca.load_ca(ca.ca_dir()), ("127.0.0.9",), name="stale")
    (folder / "tls-cert.pem").write_bytes(cert)
    (folder / "tls-key.pem").write_bytes(key)
    before = secure.deployed.fleet.brokers()["src"]
    assert before.tls_renew == "for other addresses"  # type: ignore[attr-defined]
    agents = ["--agents", str(secure.deployed.fleet.agents_file)]
    capsys.readouterr()
    assert main(["plan", str(secure.deployed.plant), *agents]) == 0
    out = capsys.readouterr().out
    assert "~ broker.src will be updated" in out and "its TLS certificate is due (for other addresses)" in out
    assert "BEGIN" not in out and "PRIVATE" not in out
    assert main(["apply", str(secure.deployed.plant), *agents, "--yes"]) == 0
    after = secure.deployed.fleet.brokers()["src"]
    assert after.pid != before.pid and after.tls_renew is None  # type: ignore[attr-defined]
    assert ca.needs_new_cert((folder / "tls-cert.pem").read_bytes(), ca.load_ca(ca.ca_dir()), (SRC_HOST,)) is None
    capsys.readouterr()
    assert main(["plan", str(secure.deployed.plant), *agents]) == 0
    assert "No changes" in capsys.readouterr().out


def test_keys_are_0600_and_no_file_holds_a_plant_secret(secure: Secure) -> None:
    for host, broker in ((SRC_HOST, "src"), (DST_HOST, "dst")):
        folder = secure.deployed.fleet.agents[host].state_dir / "brokers" / broker
        for name in ("tls-key.pem", "tls-cert.pem", "dynamic-security.json", "mosquitto.conf"):
            assert stat.S_IMODE((folder / name).stat().st_mode) == 0o600, (broker, name)
    for agent in secure.deployed.fleet.agents.values():
        assert stat.S_IMODE((agent.state_dir / "tls" / "key.pem").stat().st_mode) == 0o600
        for path in agent.state_dir.rglob("*"):
            if path.is_file():
                data = path.read_bytes()
                for password in secure.passwords.values():
                    assert password.encode() not in data, path
