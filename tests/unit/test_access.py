"""Broker users and ACLs derived from the graph (engine.derived.access, ontology/plantkg-access.ttl).

Each case is a small plant and what derive must make of it; both reasoners must agree."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.derived.access import AccessNotSupportedError
from engine.derive import derive
from engine.model import BrokerUser
from engine.reasoning.reason import reason
from kg.load import load_plant
from kg.validate import validate

HEADER = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix ex: <http://example.org/access#> .
ex:m a pk:Broker ; pk:id "m1" ; pk:name "cell-mqtt" ; pk:brokerType "mosquitto" ; pk:ip "127.0.0.1" ;
    pk:port 1883 ; pk:hasTopic ex:pose , ex:cmd .
ex:pose a pk:Topic ; pk:id "pose" ; pk:name "cell/pose" .
ex:cmd a pk:Topic ; pk:id "cmd" ; pk:name "cell/cmd" .
ex:plc a pk:Resource ; pk:id "plc" ; pk:name "PLC" ; pk:sendsTo ex:m ; pk:publishes ex:cmd .
"""
ROBOT = """ex:robot a pk:Resource ; pk:id "robot1" ; pk:name "Robot" ; pk:sendsTo ex:m ;
    pk:publishes ex:pose ; pk:subscribes ex:cmd ; pk:secretRef "env:ROBOT1_PASSWORD" .
"""
HMI = """ex:hmi a pk:Resource ; pk:id "hmi" ; pk:name "HMI" ; pk:sendsTo ex:m ; pk:subscribes ex:pose ;
    pk:secretRef "file:/etc/plantkg/hmi.pw" .
"""
ROBOT_USER = BrokerUser("robot1", "env:ROBOT1_PASSWORD", write=("cell/pose",), read=("cell/cmd",))
HMI_USER = BrokerUser("hmi", "file:/etc/plantkg/hmi.pw", read=("cell/pose",))

CERT_LISTENER = "ex:m pk:tls true ; pk:certificatePort 8884 .\n"
CAMERA = """ex:cam a pk:Resource ; pk:id "cam1" ; pk:name "Camera" ; pk:sendsTo ex:m ;
    pk:publishes ex:pose ; pk:clientCertificate true .
"""
CAMERA_USER = BrokerUser("cam1", None, write=("cell/pose",), certificate=True)

# name: (extra Turtle, users of m1, allow_anonymous of m1)
CASES = {
    "nobody-has-a-secret": ("", (), False),  # closed by default: nobody but plantkg gets in
    "two-users-close-the-broker": (ROBOT + HMI, (HMI_USER, ROBOT_USER), False),
    "the-plant-keeps-it-open": (ROBOT + "ex:m pk:allowAnonymous true .", (ROBOT_USER,), True),
    "the-plant-closes-it-without-users": ("ex:m pk:allowAnonymous false .", (), False),
    # a watcher granted a read it does not subscribe to (an asserted pk:mayRead)
    "an-asserted-right": ('ex:w a pk:Resource ; pk:id "watch" ; pk:name "Watcher" ; pk:sendsTo ex:m ; '
                          'pk:mayRead ex:pose ; pk:secretRef "env:W" .',
                          (BrokerUser("watch", "env:W", read=("cell/pose",)),), False),
    # a certificate user gets no password; one with a secret too keeps it (both ways in);
    # clientCertificate false is as if absent
    "a-certificate-user": (CERT_LISTENER + CAMERA, (CAMERA_USER,), False),
    "a-certificate-and-password-user": (CERT_LISTENER + ROBOT + "ex:robot pk:clientCertificate true .",
                                        (BrokerUser("robot1", "env:ROBOT1_PASSWORD", write=("cell/pose",),
                                                    read=("cell/cmd",), certificate=True),), False),
    "certificate-false-is-no-certificate": (CERT_LISTENER + ROBOT + "ex:robot pk:clientCertificate false . "
                                            "ex:plc pk:clientCertificate false .", (ROBOT_USER,), False),
    # a right on a topic this broker does not carry is not in its ACL
    "a-right-elsewhere": (ROBOT + 'ex:far a pk:Topic ; pk:id "far" ; pk:name "far/away" . '
                          'ex:robot pk:mayWrite ex:far .', (ROBOT_USER,), False),
}


def derived(tmp_path: Path, extra: str, engine: str = "fast"):
    plant_file = tmp_path / "plant.ttl"
    plant_file.write_text(HEADER + extra, encoding="utf-8")
    plant = load_plant([plant_file])
    reason(plant, engine=engine)  # type: ignore[arg-type]
    return derive(plant)


@pytest.mark.parametrize("engine", ["fast", "owlready2"])
@pytest.mark.parametrize("name", sorted(CASES))
def test_users_and_acls_come_from_the_graph(tmp_path: Path, name: str, engine: str) -> None:
    extra, users, anonymous = CASES[name]
    [broker] = derived(tmp_path, extra, engine).brokers
    assert (broker.users, broker.allow_anonymous) == (users, anonymous)


@pytest.mark.parametrize("engine", ["fast", "owlready2"])
def test_the_certificate_listener_comes_from_the_graph(tmp_path: Path, engine: str) -> None:
    [broker] = derived(tmp_path, CERT_LISTENER + CAMERA, engine).brokers
    assert (broker.tls, broker.certificate_port) == (True, 8884)
    [plain] = derived(tmp_path, ROBOT, engine).brokers
    assert plain.certificate_port is None


def test_a_kafka_with_users_is_closed_and_its_bridge_worker_allowed(tmp_path: Path) -> None:
    """The historian reads cell/pose on Kafka: a closed Kafka (SASL users, ACLs); the worker that
    bridges the pose from the (open) Mosquitto reaches it as plantkg's own principal."""
    kafka = ('ex:k a pk:Broker ; pk:id "k1" ; pk:name "k" ; pk:brokerType "kafka" ; pk:ip "127.0.0.2" ; '
             'pk:port 9092 ; pk:hasTopic ex:pose .\n'
             'ex:hist a pk:Resource ; pk:id "hist" ; pk:name "Historian" ; pk:sendsTo ex:k ; '
             'pk:subscribes ex:pose ; pk:secretRef "env:HIST" .\n'
             'ex:cam a pk:Resource ; pk:id "cam" ; pk:name "Camera" ; pk:sendsTo ex:m ; pk:publishes ex:pose .\n')
    state = derived(tmp_path, kafka)
    k1 = state.broker("k1")
    assert k1 is not None and (k1.users, k1.allow_anonymous) == (
        (BrokerUser("hist", "env:HIST", read=("cell/pose",)),), False)
    assert [(b.local.id, b.remote.id) for b in state.bridges] == [("m1", "k1")]


CLUSTER = ('ex:c a pk:Broker ; pk:id "c" ; pk:name "c" ; pk:brokerType "kafka" ; pk:hasTopic ex:pose .\n'
           + "".join(f'ex:n{i} a pk:Broker ; pk:id "n{i}" ; pk:name "n{i}" ; pk:brokerType "kafka" ; '
                     f'pk:ip "127.0.0.{i + 1}" ; pk:port 9092 ; pk:nodeOf ex:c ; pk:nodeId {i} ; '
                     'pk:kafkaRole "broker" , "controller" ; pk:controllerPort 9093 .\n' for i in (1, 2, 3)))
HIST = ('ex:hist a pk:Resource ; pk:id "hist" ; pk:name "Historian" ; pk:sendsTo ex:c ; '
        'pk:subscribes ex:pose ; pk:secretRef "env:HIST" .\n')

# name: (extra Turtle, users of every node, allow_anonymous of every node)
CLUSTER_CASES = {
    "a-cluster-is-closed-by-default": ("", (), False),
    "a-cluster-client-with-a-secret-is-a-user-of-every-node": (
        HIST, (BrokerUser("hist", "env:HIST", read=("cell/pose",)),), False),
    "the-plant-closes-the-cluster": ("ex:c pk:allowAnonymous false .", (), False),
    "the-plant-opens-the-cluster": ("ex:c pk:allowAnonymous true .", (), True),
}


@pytest.mark.parametrize("engine", ["fast", "owlready2"])
@pytest.mark.parametrize("name", sorted(CLUSTER_CASES))
def test_a_kafka_clusters_nodes_are_closed_together_with_the_clusters_users(
        tmp_path: Path, name: str, engine: str) -> None:
    extra, users, anonymous = CLUSTER_CASES[name]
    state = derived(tmp_path, CLUSTER + extra, engine)
    nodes = [b for b in state.brokers if b.kafka is not None]
    assert sorted(b.id for b in nodes) == ["n1", "n2", "n3"]
    assert {(b.users, b.allow_anonymous) for b in nodes} == {(users, anonymous)}


def test_a_kafka_cluster_open_to_anonymous_clients_with_users_is_refused(tmp_path: Path) -> None:
    with pytest.raises(AccessNotSupportedError, match="'n1' \\(kafka\\): the plant says pk:allowAnonymous true"):
        derived(tmp_path, CLUSTER + HIST + "ex:c pk:allowAnonymous true .")


@pytest.mark.parametrize("engine", ["fast", "owlready2"])
def test_a_bridge_logs_in_to_its_remote_as_its_own_principal(tmp_path: Path, engine: str) -> None:
    """robot1 publishes cell/pose on m1, sub reads it on m2: rule R1 bridges m1 -> m2, and the
    bridge (carried by m1) is a user of m2 that may write exactly cell/pose there; m1 keeps its
    plant users only (a bridge's local side is the broker itself)."""
    other = ('ex:m2 a pk:Broker ; pk:id "m2" ; pk:name "m2" ; pk:brokerType "mosquitto" ; pk:ip "127.0.0.2" ; '
             'pk:port 1883 ; pk:hasTopic ex:pose .\n'
             'ex:sub a pk:Resource ; pk:id "sub" ; pk:name "Sub" ; pk:sendsTo ex:m2 ; pk:subscribes ex:pose .\n')
    state = derived(tmp_path, ROBOT + other, engine)
    m1, m2 = state.brokers
    [bridge] = state.bridges
    assert (bridge.local.id, bridge.remote.id) == ("m1", "m2")
    assert m1.users == (ROBOT_USER,) and m1.allow_anonymous is False
    assert m2.users == (BrokerUser("plantkg.bridge.m1.m2", "plantkg:principal-key", write=("cell/pose",)),)
    assert m2.allow_anonymous is False


# a resource plantkg runs itself: its type names the principal it logs in as (pk:principalName)
TOOL = """ex:runner a pk:ResourceType ; pk:id "runner" ; pk:name "Run by plantkg" ; pk:principalName "plantkg.tool" .
ex:tool a pk:Resource ; pk:id "tool" ; pk:name "Tool" ; pk:isType ex:runner ; pk:sendsTo ex:m ;
    pk:publishes ex:cmd ; pk:subscribes ex:pose .
"""
TOOL_USER = BrokerUser("plantkg.tool", "plantkg:principal-key", write=("cell/cmd",), read=("cell/pose",))
RUN_CASES = {
    "closed": ("", (TOOL_USER,), False),
    "closed-with-plant-users": (ROBOT, (TOOL_USER, ROBOT_USER), False),
    # open and no plant user: no users file, so no principal (its login is not checked there)
    "open-without-users": ("ex:m pk:allowAnonymous true .", (), True),
    "open-with-users": (ROBOT + "ex:m pk:allowAnonymous true .", (TOOL_USER, ROBOT_USER), True),
    # a second resource of the type on the broker: one principal, the union of their rights
    "two-of-a-type": ('ex:tool2 a pk:Resource ; pk:id "tool2" ; pk:name "Tool 2" ; pk:isType ex:runner ; '
                      'pk:sendsTo ex:m ; pk:subscribes ex:cmd .',
                      (BrokerUser("plantkg.tool", "plantkg:principal-key", write=("cell/cmd",),
                                  read=("cell/cmd", "cell/pose")),), False),
}


@pytest.mark.parametrize("engine", ["fast", "owlready2"])
@pytest.mark.parametrize("name", sorted(RUN_CASES))
def test_a_resource_plantkg_runs_logs_in_as_its_types_principal(tmp_path: Path, name: str, engine: str) -> None:
    extra, users, anonymous = RUN_CASES[name]
    [broker] = derived(tmp_path, TOOL + extra, engine).brokers
    assert (broker.users, broker.allow_anonymous) == (users, anonymous)


@pytest.mark.parametrize("name", ["tool", "plantkg.observer", "plantkg.agent"])
def test_a_types_principal_is_one_of_plantkgs_own_and_not_a_fixed_one(tmp_path: Path, name: str) -> None:
    with pytest.raises(AccessNotSupportedError, match=f"pk:principalName '{name}'"):
        derived(tmp_path, TOOL.replace('"plantkg.tool"', f'"{name}"'))


def test_a_resource_may_not_take_a_principals_name(tmp_path: Path) -> None:
    with pytest.raises(AccessNotSupportedError, match="'plantkg.agent' has a pk:secretRef"):
        derived(tmp_path, ROBOT.replace('pk:id "robot1"', 'pk:id "plantkg.agent"'))


@pytest.mark.parametrize("engine", ["oxigraph", "pyshacl"])
@pytest.mark.parametrize(("value", "ok"), [
    ('"env:ROBOT1_PASSWORD"', True), ('"file:/etc/plantkg/robot.pw"', True),
    ('"hunter2-secret"', False), ('"file:relative.pw"', False), ('"env:1X"', False),
    ('"env:X"@en', False), ("42", False),
])
def test_a_secret_reference_is_never_a_secret(tmp_path: Path, value: str, ok: bool, engine: str) -> None:
    plant_file = tmp_path / "plant.ttl"
    plant_file.write_text(HEADER + ROBOT.replace('"env:ROBOT1_PASSWORD"', value), encoding="utf-8")
    report = validate(load_plant([plant_file]), engine=engine)  # type: ignore[arg-type]
    found = [r for r in report.violations if str(r.path).endswith("secretRef")]
    if ok:
        assert not found
    elif value.startswith('"') and value.endswith('"'):  # a plain string: maybe a password, not shown
        assert len(found) == 1 and "never the password" in found[0].message and found[0].value == "(not shown)"
    else:  # not a plain string at all: the datatype shape says so
        assert len(found) == 1 and "a plain string" in found[0].message
    text = " ".join(f"{r.value} {r.message}" for r in report.results)
    assert "hunter2" not in text  # the value is not shown: it may be a password


# --- what plans and status say about who may use a broker ---------------------------------------

def _spec(**kw):
    from engine.model import BrokerSpec  # noqa: PLC0415
    return BrokerSpec(**{"id": "m1", "iri": "urn:m1", "name": "m1", "kind": "mosquitto",
                         "host": "127.0.0.1", "port": 1883, **kw})


@pytest.mark.parametrize(("spec", "label", "warning"), [
    (_spec(), "open", "its spec does not close it"),
    (_spec(allow_anonymous=True, users=(ROBOT_USER,)), "open + users (1)", "the plant says pk:allowAnonymous true"),
    (_spec(allow_anonymous=False, users=(ROBOT_USER, HMI_USER)), "users (2)", None),
    (_spec(allow_anonymous=False, users=(ROBOT_USER,), tls=True), "users (1), TLS", None),
    (_spec(allow_anonymous=True, tls=True), "open, TLS", "the plant says pk:allowAnonymous true"),
    (_spec(allow_anonymous=False, users=(CAMERA_USER,), tls=True, certificate_port=8884),
     "users (1), TLS, certificates :8884", None),
    (_spec(kind="kafka", port=9092), "open", "its spec does not close it"),
    (_spec(kind="kafka", port=9092, allow_anonymous=False), "users (0)", None),
    (_spec(kind="kafka", port=9092, allow_anonymous=True), "open", "the plant says pk:allowAnonymous true"),
    (_spec(kind="kafka", port=9092, allow_anonymous=False, users=(HMI_USER,)), "users (1)", None),
    (_spec(kind="ngsi-v2", allow_anonymous=False), "token", None),
    (_spec(kind="ngsi-v2", allow_anonymous=True), "open", "may read and change every entity"),
    (_spec(kind="ngsi-v2", allow_anonymous=False, users=(ROBOT_USER, HMI_USER)), "principals (2)", None),
    (_spec(kind="ngsi-v2", allow_anonymous=False, tls=True), "token, TLS", None),
    (_spec(kind="ngsi-v2", allow_anonymous=False, users=(ROBOT_USER,), tls=True), "principals (1), TLS", None),
])
def test_plans_and_status_say_who_may_use_a_broker(spec, label: str, warning: str | None) -> None:
    from engine.derived.access import access_label, open_broker_warnings  # noqa: PLC0415
    assert access_label(spec) == label
    warnings = open_broker_warnings([spec])
    assert (warnings == ()) if warning is None else (len(warnings) == 1 and warning in warnings[0])


def test_an_open_kafka_cluster_node_warns_and_says_how_to_close_it() -> None:
    from engine.derived.access import open_broker_warnings  # noqa: PLC0415
    from engine.model import KafkaNode  # noqa: PLC0415
    node = _spec(kind="kafka", port=9092, allow_anonymous=True,
                 kafka=KafkaNode("plant", "A" * 22, 1, ("broker", "controller"), ()))
    [warning] = open_broker_warnings([node])
    assert "a node of Kafka cluster plant, which says pk:allowAnonymous true" in warning
    assert "remove pk:allowAnonymous from cluster plant (closed by default)" in warning
    closed = _spec(kind="kafka", port=9092, allow_anonymous=False,
                   kafka=KafkaNode("plant", "A" * 22, 1, ("broker", "controller"), ()))
    assert open_broker_warnings([closed]) == ()


def test_a_kafka_open_to_anonymous_clients_with_users_is_refused() -> None:
    from engine.derived.access import check_access_supported  # noqa: PLC0415
    check_access_supported([_spec(kind="kafka", port=9092, allow_anonymous=False, users=(ROBOT_USER,))])
    with pytest.raises(AccessNotSupportedError, match="authenticates every client \\(SASL\\) or none") as exc:
        check_access_supported([_spec(kind="kafka", port=9092, allow_anonymous=True, users=(ROBOT_USER,))])
    assert "remove pk:allowAnonymous" in str(exc.value.hint)


def test_principals_on_a_context_broker_are_taken_and_an_open_one_with_them_refused() -> None:
    from engine.derived.access import check_access_supported  # noqa: PLC0415
    check_access_supported([_spec(kind="ngsi-v2", allow_anonymous=False, users=(ROBOT_USER,))])
    with pytest.raises(AccessNotSupportedError, match="pk:allowAnonymous true, but its clients"):
        check_access_supported([_spec(kind="ngsi-v2", allow_anonymous=True, users=(ROBOT_USER,))])


KAFKA_AND_CB = """ex:k a pk:Broker ; pk:id "k1" ; pk:name "plant-kafka" ; pk:brokerType "kafka" ; pk:ip "127.0.0.4" ;
    pk:port 9092 ; pk:hasTopic ex:pose .
ex:cb a pk:Broker ; pk:id "cb1" ; pk:name "context" ; pk:brokerType "ngsi-v2" ; pk:ip "127.0.0.5" ;
    pk:port 1026 ; pk:hasTopic ex:state .
ex:state a pk:Topic ; pk:id "state" ; pk:name "cell/state" .
ex:agv a pk:Resource ; pk:id "agv" ; pk:name "AGV" ; pk:sendsTo ex:cb ; pk:publishes ex:state .
"""


@pytest.mark.parametrize(("kafka_extra", "told"), [
    ("", ("127.0.0.4:9092",)),                                   # closed by default
    ("ex:k pk:allowAnonymous true .", ()),                        # open: its notifications go anonymous
])
def test_a_context_broker_is_told_the_plants_closed_kafkas(tmp_path: Path, kafka_extra: str, told: tuple) -> None:
    """Its kafka:// notifications log in as plantkg there, and nowhere else (engine.derived.access)."""
    desired = derived(tmp_path, KAFKA_AND_CB + kafka_extra)
    specs = {b.id: b for b in desired.brokers}
    assert specs["cb1"].closed_kafkas == told
    assert specs["k1"].closed_kafkas == () and specs["m1"].closed_kafkas == ()  # only context brokers


def test_closed_kafkas_name_ipv6_addresses_in_brackets_and_count_a_clusters_broker_nodes() -> None:
    from engine.derived.access import with_plant_kafkas  # noqa: PLC0415
    from engine.model import KafkaNode  # noqa: PLC0415
    node = _spec(id="n1", kind="kafka", host="127.0.0.7", port=9092, allow_anonymous=True,
                 kafka=KafkaNode("plant", "A" * 22, 1, ("broker", "controller"), ()))
    closed = _spec(id="c1", kind="kafka", host="127.0.0.8", port=9092, allow_anonymous=False,
                   kafka=KafkaNode("site", "B" * 22, 1, ("broker",), ()))
    voter = _spec(id="c0", kind="kafka", host="127.0.0.8", port=9093, allow_anonymous=False,
                  kafka=KafkaNode("site", "B" * 22, 0, ("controller",), ()))  # serves no client
    specs = with_plant_kafkas([_spec(id="k6", kind="kafka", host="::1", port=9092, allow_anonymous=False),
                                _spec(id="k4", kind="kafka", host="127.0.0.4", port=9094, allow_anonymous=False),
                                _spec(id="open", kind="kafka", host="127.0.0.6", port=9092, allow_anonymous=True),
                                node, closed, voter, _spec(id="cb", kind="ngsi-v2", allow_anonymous=False)])
    assert specs[-1].closed_kafkas == ("127.0.0.4:9094", "127.0.0.8:9092", "[::1]:9092")


def test_a_context_broker_is_told_the_plants_kafkas_that_speak_tls() -> None:
    """Its kafka:// notifications reach them over TLS, a TLS cluster's nodes included."""
    from engine.derived.access import with_plant_kafkas  # noqa: PLC0415
    from engine.model import KafkaNode  # noqa: PLC0415
    node = _spec(id="n1", kind="kafka", host="127.0.0.7", port=9092, allow_anonymous=True, tls=True,
                 kafka=KafkaNode("plant", "A" * 22, 1, ("broker", "controller"), ()))
    specs = with_plant_kafkas([_spec(id="kt", kind="kafka", host="127.0.0.4", port=9093, allow_anonymous=False, tls=True),
                                _spec(id="ot", kind="kafka", host="::1", port=9094, allow_anonymous=True, tls=True),
                                _spec(id="kp", kind="kafka", host="127.0.0.5", port=9092, allow_anonymous=False),
                                _spec(id="m", kind="mosquitto", host="127.0.0.6", port=8883, tls=True),
                                node, _spec(id="cb", kind="ngsi-v2", allow_anonymous=False)])
    assert specs[-1].tls_kafkas == ("127.0.0.4:9093", "127.0.0.7:9092", "[::1]:9094")
    assert specs[-1].closed_kafkas == ("127.0.0.4:9093", "127.0.0.5:9092")  # n1's cluster is open
    assert all(s.tls_kafkas == () for s in specs[:-1])  # only context brokers are told
