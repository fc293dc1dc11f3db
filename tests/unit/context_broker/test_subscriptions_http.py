"""The pure parts of HTTP notifications: which answers are retried, the URL with ``qs``, the
headers (custom ones cannot replace the format or the correlator)."""

from __future__ import annotations

import pytest

from engine.context_broker.subscriptions.http import classify, request_headers, request_url
from engine.context_broker.subscriptions.model import HttpTarget
from engine.context_broker.subscriptions.render import Outgoing

# (status, ok, retried)
ANSWERS = [(200, True, False), (201, True, False), (204, True, False), (301, False, False),
           (400, False, False), (404, False, False), (408, False, True), (429, False, True),
           (500, False, True), (503, False, True)]


@pytest.mark.parametrize("code,ok,retry", ANSWERS)
def test_classify(code: int, ok: bool, retry: bool) -> None:
    result = classify(code)
    assert (result.ok, result.retry, result.code) == (ok, retry, code)
    assert ok or str(code) in result.reason


def test_url_with_qs_keeps_the_existing_query() -> None:
    target = HttpTarget("http://h:1/n?a=1", custom=True, qs=(("token", "a b"), ("x", "é")))
    assert request_url(target) == "http://h:1/n?a=1&token=a+b&x=%C3%A9"
    assert request_url(HttpTarget("http://h:1/n")) == "http://h:1/n"


def test_headers() -> None:
    msg = Outgoing("s" * 24, b"{}", "keyValues", "", "/", "E1", "corr-1")
    target = HttpTarget("http://h/n", custom=True, headers=(("X-A", "1"), ("ngsiv2-attrsformat", "x"),
                                                           ("Fiware-Correlator", "mine")))
    headers = request_headers(target, msg)
    assert headers["Ngsiv2-AttrsFormat"] == "keyValues" and headers["Fiware-Correlator"] == "corr-1"
    assert "ngsiv2-attrsformat" not in headers and headers["X-A"] == "1"
    assert headers["Content-Type"] == "application/json" and headers["Fiware-ServicePath"] == "/"
    assert "Fiware-Service" not in headers  # the default tenant sends none, as Orion
