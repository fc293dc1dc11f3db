"""A closed Kafka cluster's users and ACLs awaited on every node (issue 13), the parts without a
broker: what a node's report lacks of what the plant wants (cases as data), the polling and its
typed error, and when the driver has nothing to wait for. The wait against three real nodes is in
tests/integration/test_kafka_cluster_closed.py."""

from __future__ import annotations

import time
from dataclasses import replace

import pytest

from engine import netutil
from engine.drivers.kafka import spread
from engine.drivers.kafka.driver import KafkaDriver
from engine.errors import AccessNotSpreadError, BrokerUnavailableError
from engine.model import BrokerSpec, BrokerUser, KafkaNode, KafkaVoter

PLC = BrokerUser("plc", "env:PW_PLC", write=("line.energy",))
MES = BrokerUser("mes", "env:PW_MES", read=("line.energy",))
HMI = BrokerUser("hmi", "env:PW_HMI", write=("plant.kpi",))
# Kafka's codes, as a node reports them: TOPIC 2, GROUP 3; LITERAL 3; READ 3, WRITE 4, DESCRIBE 8; ALLOW 3
PLC_WRITE = (2, "line.energy", 3, "User:plc", "*", 4, 3)
HMI_WRITE = (2, "plant.kpi", 3, "User:hmi", "*", 4, 3)
HMI_DESCRIBE = (2, "plant.kpi", 3, "User:hmi", "*", 8, 3)
FOREIGN = (2, "plant.kpi", 3, "User:eve", "*", 3, 3)


def node(users: tuple[BrokerUser, ...], *, drop: tuple[str, ...] = (), add: tuple[str, ...] = (),
         without: tuple[tuple, ...] = (), extra: tuple[tuple, ...] = ()) -> spread.NodeAccess:
    """What a node reports: the access of ``users`` less ``drop``/``without``, plus ``add``/``extra``."""
    want = spread.wanted(users)
    return spread.NodeAccess((want.users - set(drop)) | set(add), (want.acls - set(without)) | set(extra))


#: (case, the plant's users, what the node reports, what it lacks or still has)
CASES = [
    ("caught up", (PLC, MES), node((PLC, MES)), ()),
    ("no users at all, none reported", (), node(()), ()),
    ("a user added: the node has neither it nor its ACLs yet", (PLC, HMI), node((PLC,)),
     ("lacks user 'hmi'", "lacks ACL ALLOW User:hmi WRITE on TOPIC 'plant.kpi'",
      "lacks ACL ALLOW User:hmi DESCRIBE on TOPIC 'plant.kpi'")),
    ("the user is there, its ACLs not yet", (PLC, HMI), node((PLC, HMI), without=(HMI_WRITE, HMI_DESCRIBE)),
     ("lacks ACL ALLOW User:hmi WRITE on TOPIC 'plant.kpi'", "lacks ACL ALLOW User:hmi DESCRIBE on TOPIC 'plant.kpi'")),
    ("a user removed: the node still has it and its ACLs", (PLC,), node((PLC, HMI)),
     ("still has user 'hmi'", "still has ACL ALLOW User:hmi WRITE on TOPIC 'plant.kpi'",
      "still has ACL ALLOW User:hmi DESCRIBE on TOPIC 'plant.kpi'")),
    ("an ACL nobody asked for", (PLC,), node((PLC,), extra=(FOREIGN,)),
     ("still has ACL ALLOW User:eve READ on TOPIC 'plant.kpi'",)),
    ("a user replaced: its credential gone, its ACLs not yet; the new one not there",
     (MES, HMI), node((PLC, MES), drop=("plc",)),
     ("lacks user 'hmi'", "lacks ACL ALLOW User:hmi WRITE on TOPIC 'plant.kpi'",
      "lacks ACL ALLOW User:hmi DESCRIBE on TOPIC 'plant.kpi'",
      "still has ACL ALLOW User:plc WRITE on TOPIC 'line.energy'",
      "still has ACL ALLOW User:plc DESCRIBE on TOPIC 'line.energy'")),
    ("a user without its credential (the ACLs came first)", (PLC,), node((PLC,), drop=("plc",)),
     ("lacks user 'plc'",)),
]


@pytest.mark.parametrize(("users", "seen", "expected"), [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_what_a_node_lacks(users: tuple[BrokerUser, ...], seen: spread.NodeAccess, expected: tuple[str, ...]) -> None:
    assert spread.differences(spread.wanted(users), seen) == expected


def test_the_plant_wants_kafkas_codes_for_each_right() -> None:
    want = spread.wanted((PLC, MES))
    assert want.users == {"plc", "mes"}
    assert PLC_WRITE in want.acls
    assert (3, "*", 3, "User:mes", "*", 3, 3) in want.acls  # READ on every consumer group
    assert spread.describe_acl(PLC_WRITE) == "ALLOW User:plc WRITE on TOPIC 'line.energy'"


def test_the_wait_returns_once_every_node_caught_up() -> None:
    asked: list[str] = []
    behind = {"n2:9092": 3}  # n2 lags for its first three answers

    def lag(address: str) -> tuple[str, ...]:
        asked.append(address)
        if behind.get(address, 0) > 0:
            behind[address] -= 1
            return ("lacks user 'hmi'",)
        return ()

    spread.wait_every_node("c", ("n1:9092", "n2:9092", "n3:9092"), (HMI,), spread.Login("pw"), 10.0, lag=lag)
    # a node that caught up is not asked again
    assert asked.count("n1:9092") == 1 and asked.count("n3:9092") == 1 and asked.count("n2:9092") == 4


def test_a_node_that_stays_behind_is_named_with_what_it_lacks() -> None:
    def lag(address: str) -> tuple[str, ...]:
        return () if address == "n1:9092" else ("lacks user 'hmi'", "lacks ACL ALLOW User:hmi WRITE on TOPIC 'plant.kpi'")

    began = time.monotonic()
    with pytest.raises(AccessNotSpreadError) as info:
        spread.wait_every_node("plant-kafka", ("n1:9092", "n2:9092", "n3:9092"), (HMI,), spread.Login("pw"), 0.3,
                               lag=lag)
    assert time.monotonic() - began < 5
    error = info.value
    assert isinstance(error, BrokerUnavailableError) and error.retryable  # the engine tries the PUT again
    assert error.node == "n2:9092" and error.cluster == "plant-kafka"
    assert "node n2:9092 does not enforce" in error.message and "lacks user 'hmi'" in error.message
    assert "nor yet node(s) n3:9092" in error.message
    assert error.hint and "metadata log" in error.hint


def _cluster_lead(**changes: object) -> BrokerSpec:
    port = netutil.free_port()  # nothing listens there
    node = KafkaNode(cluster="plant-kafka", cluster_id="A" * 22, node_id=1, roles=("broker", "controller"),
                     voters=(KafkaVoter(1, "127.0.0.1", port),), bootstrap=(f"127.0.0.1:{port}",), lead=True)
    spec = BrokerSpec(id="n1", iri="https://example.org/p#n1", name="n1", kind="kafka", host="127.0.0.1",
                      port=port, kafka=node, users=(HMI,))
    return replace(spec, **changes)  # type: ignore[arg-type]


def test_the_driver_waits_only_for_a_closed_clusters_lead(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("PW_HMI", "hmi-password")
    driver = KafkaDriver()
    driver.settle_deadline = 0.3
    lead = _cluster_lead()
    for nothing_to_wait_for in (replace(lead, kafka=None),  # a node alone
                                replace(lead, kafka=replace(lead.kafka, lead=False)),  # another node
                                replace(lead, users=(), allow_anonymous=True)):  # an open cluster
        began = time.monotonic()
        driver.settle(nothing_to_wait_for)
        assert time.monotonic() - began < 0.2
    with pytest.raises(AccessNotSpreadError, match="did not answer"):
        driver.settle(lead)  # its one node does not run
