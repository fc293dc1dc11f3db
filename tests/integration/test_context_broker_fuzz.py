"""The context broker fuzzed with schemathesis against its own OpenAPI document.

The real process serves ``/plantkg/v1/openapi.json``; schemathesis generates requests for every
operation it documents (valid ones and, in negative mode, invalid ones), with the bearer token
so writes are exercised, a few examples per operation (derandomized: the same requests on every
run, the test stays under a minute on two shared cores). Checks: no 5xx, and every status code
answered is one the document lists for that operation. The store is seeded, so generated ids
sometimes hit existing entities. After the run the server's log must hold no traceback.
"""

from __future__ import annotations

import json
from collections.abc import Iterator

import pytest
import schemathesis
from hypothesis import HealthCheck, settings
from schemathesis.checks import not_a_server_error
from schemathesis.specs.openapi.checks import status_code_conformance

from benchmarks.context_broker_rig import OPENAPI_PATH, ContextBroker

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


@pytest.fixture(scope="module")
def api_schema(broker: ContextBroker) -> schemathesis.BaseSchema:
    config = schemathesis.Config()
    return schemathesis.openapi.from_url(broker.url + OPENAPI_PATH, config=config, timeout=10)


schema = schemathesis.pytest.from_fixture("api_schema")


@schema.parametrize()
@settings(max_examples=MAX_EXAMPLES, deadline=None, derandomize=True, database=None,
          suppress_health_check=list(HealthCheck))
def test_no_server_error_and_only_documented_status_codes(case: schemathesis.Case, broker: ContextBroker) -> None:
    case.call_and_validate(headers=broker.auth, checks=[not_a_server_error, status_code_conformance], timeout=10)


def test_fuzzing_left_no_traceback_in_the_log(broker: ContextBroker) -> None:
    """Runs after the fuzz test in this module (file order): what the fuzzer sent was answered,
    never crashed a handler."""
    http = broker.http()
    assert http.request("GET", "/version").status == 200
    http.close()
    log = broker.log_text()
    assert "Traceback" not in log, log[-4000:]
