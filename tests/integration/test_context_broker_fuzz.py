"""The context broker fuzzed with schemathesis against its own OpenAPI document.

The real process serves ``/plantkg/v1/openapi.json``; schemathesis generates requests for every
operation it documents, valid ones (positive mode) and invalid ones (negative mode), with the
bearer token so writes are exercised, ``MAX_EXAMPLES`` per operation and mode (derandomized: the
same requests on every run; no shrinking, so a failure costs no extra minute). Checks: no 5xx,
every status code answered is one the document lists for that operation, with the documented
content type and body schema (Orion's error body for errors). The store is
seeded, so generated ids sometimes hit existing entities. The log must hold no traceback after.

schemathesis's pytest loader (``schemathesis.pytest.from_fixture``) does not run on pytest 9
(it sets ``Node._nodeid``), so the operations are walked here with its Python API: one
Hypothesis run per operation and mode over ``APIOperation.as_strategy``, every failure kept and
reported together.
"""

from __future__ import annotations

import json
from collections.abc import Iterator

import pytest
import schemathesis
from hypothesis import HealthCheck, Phase, given, settings
from schemathesis import GenerationMode
from schemathesis.checks import not_a_server_error
from schemathesis.core.failures import FailureGroup
from schemathesis.specs.openapi.checks import (content_type_conformance, response_schema_conformance,
                                              status_code_conformance)

from benchmarks.context_broker_rig import OPENAPI_PATH, ContextBroker

pytestmark = pytest.mark.integration

MAX_EXAMPLES = 8
CHECKS = [not_a_server_error, status_code_conformance, content_type_conformance, response_schema_conformance]
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


def fuzz(operation: schemathesis.APIOperation, mode: GenerationMode, broker: ContextBroker) -> str | None:
    """Run ``MAX_EXAMPLES`` generated requests; the first failure's report, or None."""
    calls = [0]

    @given(case=operation.as_strategy(generation_mode=mode))
    @settings(max_examples=MAX_EXAMPLES, deadline=None, derandomize=True, database=None,
              phases=[Phase.explicit, Phase.generate], suppress_health_check=list(HealthCheck))
    def run(case: schemathesis.Case) -> None:
        calls[0] += 1
        case.call_and_validate(headers=broker.auth, checks=CHECKS,
                               timeout=10)

    try:
        run()
    except (Exception, FailureGroup) as err:  # FailureGroup: a BaseExceptionGroup of failed checks
        return f"{operation.label} ({mode.value}): {err}"
    assert calls[0] > 0, f"{operation.label} ({mode.value}): no request generated"
    return None


def test_every_operation_fuzzed_without_5xx_or_undocumented_status(broker: ContextBroker) -> None:
    schema = schemathesis.openapi.from_url(broker.url + OPENAPI_PATH, config=schemathesis.Config(), timeout=10)
    operations = [result.ok() for result in schema.get_all_operations()]
    assert len(operations) >= 20, [op.label for op in operations]  # entities, attrs, types, batch, subscriptions
    failures = [f for op in operations for mode in (GenerationMode.POSITIVE, GenerationMode.NEGATIVE)
                if (f := fuzz(op, mode, broker)) is not None]
    assert not failures, "\n\n".join(failures)
    http = broker.http()
    assert http.request("GET", "/version").status == 200
    http.close()
    log = broker.log_text()
    assert "Traceback" not in log, log[-4000:]
