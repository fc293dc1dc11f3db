"""AgentClient.batch against a real agent (in a thread, real Mosquitto): a result per call with
the error the single call would raise, the agent's state afterwards, many lanes split into
several requests, a refused request raised as a single call's would be."""

from __future__ import annotations

import pytest

from engine import netutil
from engine.agent import client as client_module
from engine.agent.calls import AgentCall
from engine.agent.client import AgentClient
from engine.agent.server import RunningAgent
from engine.errors import AgentAuthError, PermanentDispatchError
from engine.model import BrokerSpec, BrokerStatus, TopicSpec
from tests.unit.test_agent_client import TOKEN, agent, client, driver

__all__ = ["agent", "client", "driver"]  # the fixtures of test_agent_client, used here


def mqtt(broker_id: str, port: int | None = None) -> BrokerSpec:
    return BrokerSpec(broker_id, f"urn:plant:{broker_id}", "MQTT", "mosquitto", "127.0.0.1",
                      port or netutil.free_port())


def test_results_per_call_and_the_state_afterwards(client: AgentClient) -> None:
    answer = client.batch([
        [AgentCall("put_broker", (mqtt("a"),), owner="cell"),
         AgentCall("put_topic", (TopicSpec("a", "t/1", "urn:t", qos=1),), owner="cell")],
        [AgentCall("put_topic", (TopicSpec("ghost", "t", "urn:t"),)),
         AgentCall("delete_broker", ("ghost",))],
    ], observe=True)
    (put, topic), (missing, skipped) = answer.lanes
    assert put.done and topic.done and skipped.skipped
    assert isinstance(missing.error, PermanentDispatchError)
    assert "PUT /v1/brokers/ghost/topics/t -> 404: no broker 'ghost'" in missing.error.message
    assert answer.observed and [b.spec.id for b in answer.brokers] == ["a"]  # type: ignore[union-attr]
    (broker,) = answer.brokers  # type: ignore[misc]
    assert broker.status is BrokerStatus.RUNNING and broker.owner == "cell" and broker.topics[0].qos == 1
    assert answer.bridges == ()
    # another plant's delete is refused for that call only
    refused = client.batch([[AgentCall("delete_broker", ("a",), owner="other")]])
    assert "owned by plant 'cell'" in refused.lanes[0][0].error.message  # type: ignore[union-attr]
    assert not refused.observed
    assert client.batch([[AgentCall("delete_broker", ("a",), owner="cell")]]).lanes[0][0].done
    assert client.list_brokers() == []


def test_many_lanes_go_as_several_requests_in_order(client: AgentClient, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(client_module, "BATCH_LANES", 2)
    specs = [mqtt(f"m{i}") for i in range(5)]
    answer = client.batch([[AgentCall("put_broker", (s,))] for s in specs]
                          + [[AgentCall("delete_topic", ("nowhere", "t"))]], observe=True)
    assert [lane[0].done for lane in answer.lanes] == [True] * 6
    assert not answer.observed  # several requests: no one moment after all of them
    assert sorted(b.spec.id for b in client.list_brokers()) == [s.id for s in specs]
    gone = client.batch([[AgentCall("delete_broker", (s.id,))] for s in specs])
    assert all(lane[0].done for lane in gone.lanes) and client.list_brokers() == []


def test_a_refused_request_raises_as_a_single_call_would(agent: RunningAgent) -> None:
    with pytest.raises(AgentAuthError):
        AgentClient(agent.address.url, "not-the-token").batch([[AgentCall("delete_broker", ("a",))]])


def test_an_agent_call_names_a_verb_and_hides_its_token() -> None:
    with pytest.raises(ValueError, match="not a batch verb"):
        AgentCall("health", ())
    call = AgentCall("delete_bridge", ("a", "b"), owner="cell", remote_token="secret-token")
    assert "secret-token" not in repr(call)
    assert call.kwargs() == {"owner": "cell", "remote_token": "secret-token"}
    assert AgentCall("delete_broker", ("a",)).kwargs() == {}


def test_the_state_is_both_lists_in_one_request(client: AgentClient) -> None:
    assert client.state() == ([], [])
    client.batch([[AgentCall("put_broker", (mqtt("a"),))]])
    brokers, bridges = client.state()
    assert brokers == client.list_brokers() and bridges == client.list_bridges() == []
    assert client.batch([[AgentCall("delete_broker", ("a",))]]).lanes[0][0].done
