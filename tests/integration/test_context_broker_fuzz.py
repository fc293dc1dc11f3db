"""The context broker fuzzed with schemathesis against its own OpenAPI document.

The real process serves ``/plantkg/v1/openapi.json``; :mod:`tests.openapi_fuzz` generates requests
for every operation it documents, valid and invalid ones, with the bearer token so writes are
exercised, ``MAX_EXAMPLES`` per operation and mode; no 5xx, only documented status codes, content
types and bodies (Orion's error body for errors). The store is seeded, so generated ids sometimes
hit existing entities. The log must hold no traceback after.
"""

from __future__ import annotations

import json
from collections.abc import Iterator

import pytest

from benchmarks.context_broker_rig import OPENAPI_PATH, ContextBroker
from tests.openapi_fuzz import fuzz_all, operations

pytestmark = pytest.mark.integration

MAX_EXAMPLES = 8
SEED = [{"id": "Room1", "type": "Room", "temperature": {"type": "Number", "value": 21.5}},
        {"id": "Agv_7", "type": "AGV", "state": {"type": "Text", "value": "idle"},
         "battery": {"type": "Number", "value": 80}}]


@pytest.fixture(scope="module")
def broker(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ContextBroker]:
    rig = ContextBroker(tmp_path_factory.mktemp("context-broker-fuzz")).start()
    try:
        http = rig.http()
        for entity in SEED:
            reply = http.request("POST", "/v2/entities", json.dumps(entity),
                                 {"Content-Type": "application/json", **rig.auth})
            assert reply.status == 201, (reply.status, reply.body)
        http.close()
        yield rig
    finally:
        child = rig.child
        rig.stop()
        assert child is None or not child.group_alive(), "the context broker survived stop()"


def test_every_operation_fuzzed_without_5xx_or_undocumented_status(broker: ContextBroker) -> None:
    ops = operations(broker.url + OPENAPI_PATH)
    assert len(ops) >= 20, [op.label for op in ops]  # entities, attrs, types, batch, subscriptions
    failures = fuzz_all(ops, broker.auth, MAX_EXAMPLES)
    assert not failures, "\n\n".join(failures)
    http = broker.http()
    assert http.request("GET", "/version").status == 200
    http.close()
    log = broker.log_text()
    assert "Traceback" not in log, log[-4000:]
