"""The SPARQL endpoint's admission rule (engine.web.sparql_limiter): per-client limit first (429),
then the global one (503). Cases as data; then the counting limiter over sequences of events."""

from __future__ import annotations

import threading

import pytest

from engine.web.sparql_limiter import QueryLimiter, Verdict, decide
from engine.web.sparql_protocol import refusal
from engine.web.sparql_types import Limits

A, B, C = "address 127.0.0.2", "address 127.0.0.1", "user operator"

# (running per client, client asking, per_client, total, verdict)
DECIDE_CASES = [
    ({}, A, 2, 4, Verdict.ADMIT),
    ({A: 1}, A, 2, 4, Verdict.ADMIT),
    ({A: 2}, A, 2, 4, Verdict.CLIENT_LIMIT),
    ({A: 2}, B, 2, 4, Verdict.ADMIT),                 # one busy client leaves the others room
    ({A: 2, B: 2}, C, 2, 4, Verdict.GLOBAL_LIMIT),
    ({A: 2, B: 2}, A, 2, 4, Verdict.CLIENT_LIMIT),    # its own limit is named first
    ({A: 1, B: 2}, A, 2, 3, Verdict.GLOBAL_LIMIT),
    ({A: 3}, A, 5, 3, Verdict.GLOBAL_LIMIT),          # per_client above total: only the total counts
    ({A: 0}, A, 1, 1, Verdict.ADMIT),
    ({B: 1}, A, 1, 1, Verdict.GLOBAL_LIMIT),
]


@pytest.mark.parametrize("running, client, per_client, total, verdict", DECIDE_CASES)
def test_decide(running: dict[str, int], client: str, per_client: int, total: int, verdict: Verdict) -> None:
    assert decide(running, client, per_client=per_client, total=total) is verdict


# Sequences of ("acquire", client, expected verdict) / ("release", client, None) on a limiter of
# per_client=2, total=3, and the counts afterwards.
SEQUENCES = [
    ([("acquire", A, Verdict.ADMIT), ("acquire", A, Verdict.ADMIT), ("acquire", A, Verdict.CLIENT_LIMIT),
      ("acquire", B, Verdict.ADMIT), ("acquire", B, Verdict.GLOBAL_LIMIT)], {A: 2, B: 1}),
    ([("acquire", A, Verdict.ADMIT), ("acquire", A, Verdict.ADMIT), ("release", A, None),
      ("acquire", A, Verdict.ADMIT), ("acquire", A, Verdict.CLIENT_LIMIT)], {A: 2}),
    ([("acquire", A, Verdict.ADMIT), ("release", A, None)], {}),  # a finished client leaves no entry
    ([("acquire", A, Verdict.ADMIT), ("acquire", B, Verdict.ADMIT), ("acquire", C, Verdict.ADMIT),
      ("acquire", C, Verdict.GLOBAL_LIMIT), ("release", B, None), ("acquire", C, Verdict.ADMIT)], {A: 1, C: 2}),
]


@pytest.mark.parametrize("events, counts", SEQUENCES)
def test_sequences(events: list[tuple[str, str, Verdict | None]], counts: dict[str, int]) -> None:
    limiter = QueryLimiter(per_client=2, total=3)
    for action, client, expected in events:
        if action == "acquire":
            assert limiter.acquire(client) is expected, (action, client)
        else:
            limiter.release(client)
    assert limiter.running() == counts


def test_a_release_without_acquire_is_a_bug_not_a_negative_count() -> None:
    limiter = QueryLimiter(per_client=1, total=1)
    with pytest.raises(RuntimeError, match="release without acquire"):
        limiter.release(A)
    assert limiter.acquire(A) is Verdict.ADMIT


@pytest.mark.parametrize("per_client, total", [(0, 4), (2, 0), (-1, -1)])
def test_limits_below_one_are_refused(per_client: int, total: int) -> None:
    with pytest.raises(ValueError, match="at least 1"):
        QueryLimiter(per_client=per_client, total=total)


def test_concurrent_acquires_never_pass_the_limits() -> None:
    limiter = QueryLimiter(per_client=3, total=5)
    clients = [f"address 127.0.0.{i % 4 + 1}" for i in range(200)]
    admitted: list[str] = []
    lock = threading.Lock()
    start = threading.Barrier(len(clients), timeout=30)

    def ask(client: str) -> None:
        start.wait()
        if limiter.acquire(client) is Verdict.ADMIT:
            with lock:
                admitted.append(client)

    threads = [threading.Thread(target=ask, args=(c,)) for c in clients]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=30)
    running = limiter.running()
    assert len(admitted) == sum(running.values()) == 5
    assert max(running.values()) <= 3


@pytest.mark.parametrize("verdict, status, words", [
    (Verdict.CLIENT_LIMIT, 429, ["from address 127.0.0.2", "at most 2 per client", "--max-client-queries",
                                 "one after another", "retry after 8 s"]),
    (Verdict.GLOBAL_LIMIT, 503, ["busy", "4 queries are running", "--max-queries", "retry after 8 s"]),
])
def test_refusals_say_the_limit_and_what_to_do(verdict: Verdict, status: int, words: list[str]) -> None:
    error = refusal(verdict, A, Limits(timeout_s=7.5, workers=4, per_client=2))
    text = error.message + "\n" + (error.hint or "")
    assert error.status == status and error.retry_after_s == 8
    assert all(w in text for w in words), text


@pytest.mark.parametrize("timeout_s, retry_after", [(0.1, 1), (1.0, 1), (10.0, 10), (10.2, 11)])
def test_retry_after_is_the_timeout_rounded_up(timeout_s: float, retry_after: int) -> None:
    assert Limits(timeout_s=timeout_s).retry_after_s == retry_after


@pytest.mark.parametrize("field", ["timeout_s", "max_rows", "workers", "per_client"])
def test_limits_must_be_positive(field: str) -> None:
    with pytest.raises(ValueError, match=f"Limits.{field} must be positive"):
        Limits(**{field: 0})
