"""Fuzz a running HTTP server against its own OpenAPI document with schemathesis.

Used by the context broker's and the agent's fuzz tests. For every operation the document lists,
schemathesis generates requests, valid ones (positive mode) and invalid ones (negative mode),
``max_examples`` per operation and mode, derandomized (the same requests on every run) and without
shrinking (a failure costs no extra minute). Checks: no 5xx, every status code answered is one the
document lists for that operation, with the documented content type and body schema.

schemathesis's pytest loader (``schemathesis.pytest.from_fixture``) does not run on pytest 9 (it
sets ``Node._nodeid``), so the operations are walked here with its Python API: one Hypothesis run
per operation and mode over ``APIOperation.as_strategy``, every failure kept and reported together.
"""

from __future__ import annotations

from collections import Counter

import schemathesis
from hypothesis import HealthCheck, Phase, given, settings
from schemathesis import GenerationMode
from schemathesis.checks import not_a_server_error
from schemathesis.core.failures import FailureGroup
from schemathesis.specs.openapi.checks import (content_type_conformance, response_schema_conformance,
                                              status_code_conformance)

CHECKS = [not_a_server_error, status_code_conformance, content_type_conformance, response_schema_conformance]
MODES = (GenerationMode.POSITIVE, GenerationMode.NEGATIVE)


def fuzz(operation: schemathesis.APIOperation, mode: GenerationMode, headers: dict[str, str],
         max_examples: int, answers: Counter[tuple[str, int]] | None = None) -> str | None:
    """Run ``max_examples`` generated requests; the first failure's report, or None. ``answers``
    counts the status codes by operation (what the requests really exercised)."""
    calls = [0]

    @given(case=operation.as_strategy(generation_mode=mode))
    @settings(max_examples=max_examples, deadline=None, derandomize=True, database=None,
              phases=[Phase.explicit, Phase.generate], suppress_health_check=list(HealthCheck))
    def run(case: schemathesis.Case) -> None:
        calls[0] += 1
        response = case.call_and_validate(headers=headers, checks=CHECKS, timeout=30)
        if answers is not None:
            answers[(operation.label, response.status_code)] += 1

    try:
        run()
    except (Exception, FailureGroup) as err:  # FailureGroup: a BaseExceptionGroup of failed checks
        return f"{operation.label} ({mode.value}): {err}"
    assert calls[0] > 0, f"{operation.label} ({mode.value}): no request generated"
    return None


def operations(document_url: str) -> list[schemathesis.APIOperation]:
    """Every operation of the document served at ``document_url``."""
    schema = schemathesis.openapi.from_url(document_url, config=schemathesis.Config(), timeout=10)
    return [result.ok() for result in schema.get_all_operations()]


def fuzz_all(ops: list[schemathesis.APIOperation], headers: dict[str, str], max_examples: int,
             answers: Counter[tuple[str, int]] | None = None) -> list[str]:
    """The failures of every operation in both modes."""
    return [f for op in ops for mode in MODES
            if (f := fuzz(op, mode, headers, max_examples, answers)) is not None]
