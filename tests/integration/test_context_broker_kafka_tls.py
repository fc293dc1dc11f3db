"""The context broker's ``kafka://`` notifications reach a closed Kafka that speaks TLS (issue 13),
end to end: ``plantkg apply`` of a plant file with a Kafka that says ``pk:tls true`` (and nothing
about anonymous clients: closed by default) and a context broker; real agents, Kafka and context
broker.

- the engine tells the context broker that Kafka is closed and speaks TLS (``closed_kafkas``,
  ``tls_kafkas``: ``--closed-kafka``, ``--tls-kafka``) and the plan has no change after apply;
- a subscription's notifications arrive, every one, in order, read back over SASL_SSL: the
  context broker produced them logged in as plantkg over TLS, trusting the plant CA;
- plantkg's Kafka password is in no log and in no file others may read; a plain client (no TLS)
  gets no metadata.
"""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from confluent_kafka import KafkaException
from confluent_kafka.admin import AdminClient

from engine.security import kafka_client
from tests.integration.agents import Deployment, deployment
from tests.integration.plant_cli import files_holding
from tests.integration.test_context_broker_kafka_closed import CB, KF, notifications_arrive
from tests.integration.test_context_broker_kafka_closed import _plant as closed_plant

pytestmark = pytest.mark.integration


def _plant(ports: dict[str, int]) -> str:
    """The closed-Kafka test's plant, its Kafka saying ``pk:tls true``."""
    text = closed_plant(ports)
    assert text.count("pk:brokerType \"kafka\" ;") == 1
    return text.replace("pk:brokerType \"kafka\" ;", "pk:brokerType \"kafka\" ; pk:tls true ;")


@pytest.fixture(scope="module")
def dep(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployment]:
    with deployment(tmp_path_factory.mktemp("cb-kafka-tls"), {"kf": KF, "cb": CB}, _plant) as made:
        yield made


def test_the_context_broker_is_told_the_kafka_speaks_tls_and_the_plan_is_settled(
        dep: Deployment, capsys: pytest.CaptureFixture[str]) -> None:
    spec = dep.fleet.brokers()["cb"].spec
    assert spec.closed_kafkas == (dep.address("kf"),) and spec.tls_kafkas == (dep.address("kf"),)
    code = dep.cli("plan", "--detailed-exitcode")
    out = capsys.readouterr().out
    assert code == 0 and "No changes." in out, out


def test_notifications_arrive_over_tls(dep: Deployment) -> None:
    notifications_arrive(dep, tls=True)


def test_a_plain_client_gets_nothing_and_the_password_stays_private(dep: Deployment) -> None:
    plain = AdminClient({"bootstrap.servers": dep.address("kf"), "log_level": 0, **kafka_client.client_settings(True)})
    with pytest.raises(KafkaException):
        plain.list_topics(timeout=5)
    _, checked = files_holding((agent.state_dir for agent in dep.fleet.agents.values()), kafka_client.password())
    assert checked > 5
