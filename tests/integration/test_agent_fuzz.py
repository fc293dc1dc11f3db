"""The agent fuzzed with schemathesis against its own OpenAPI document (issue 15: "the agent's
OpenAPI document matches it").

A real ``plantkg agent`` serves ``/v1/openapi.json``; :mod:`tests.openapi_fuzz` sends generated
requests, valid and invalid, to every operation it documents, with the agent's token so writes
are exercised: no 5xx, only documented status codes, content types and bodies. The agent's log
must hold no traceback, and no broker process may survive the agent.

What the fuzzer does not reach: a broker spec valid by the schema is still refused (400) unless
its ``id`` equals the path's and its ``ip`` is the agent's own, which a schema cannot say, so
generated PUTs do not deploy brokers; tests/integration/test_agent.py deploys real ones.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.integration.agents import AgentFleet, start_agents
from tests.openapi_fuzz import fuzz_all, operations

pytestmark = pytest.mark.integration

MAX_EXAMPLES = 6
HOST = "127.0.0.1"


@pytest.fixture
def fleet(tmp_path: Path) -> Iterator[AgentFleet]:
    agents = start_agents([HOST], tmp_path)
    try:
        yield agents
    finally:
        agents.stop()


def test_every_agent_operation_fuzzed_without_5xx_or_undocumented_status(fleet: AgentFleet, tmp_path: Path) -> None:
    agent = fleet.agents[HOST]
    ops = operations(agent.url + "/v1/openapi.json")
    labels = {op.label for op in ops}
    assert {"GET /v1/health", "PUT /v1/brokers/{broker_id}", "DELETE /v1/brokers/{broker_id}/topics/{name}",
            "PUT /v1/brokers/{broker_id}/bridges/{remote_id}"} <= labels, sorted(labels)
    answers: Counter[tuple[str, int]] = Counter()
    failures = fuzz_all(ops, {"Authorization": f"Bearer {agent.token}"}, MAX_EXAMPLES, answers)
    assert not failures, "\n\n".join(failures)
    # the fuzzer reached past the token check into every operation's own validation
    reached = {label for (label, status), _ in answers.items() if status != 401}
    assert reached == labels, sorted(labels - reached)
    assert agent.client().health()
    fleet.brokers()  # remember the pids of what the fuzzer deployed, for the no-survivor check
    logs = "\n".join(p.read_text(encoding="utf-8", errors="replace") for p in (tmp_path / "logs").glob("*.log"))
    assert "Traceback" not in logs, logs[-4000:]
