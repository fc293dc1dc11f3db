"""A control-socket request is checked field by field; each refusal names the field and its value."""

from __future__ import annotations

from typing import Any

import pytest

from engine.control.request import Request, RequestError, parse_request

KEY = {"files": ["/plant/a.ttl"], "agents": None, "owner": None}
GOOD = {"verb": "apply", "key": KEY, "yes": True, "parallelism": 4, "prune": False, "format": "json",
        "tty": False, "color": True}


def test_a_good_request() -> None:
    assert parse_request({"request": GOOD}, KEY) == Request("apply", KEY, yes=True, parallelism=4, prune=False,
                                                            fmt="json", tty=False, color=True)


def test_defaults_are_the_command_lines() -> None:
    assert parse_request({"request": {"verb": "apply", "key": KEY}}, KEY) == Request("apply", KEY)


# (what is changed, the words the refusal must hold)
REFUSED: list[tuple[dict[str, Any], tuple[str, ...]]] = [
    ({"verb": "plan"}, ("'verb'", "'plan'", "apply, destroy")),
    ({"verb": None}, ("'verb'", "None")),
    ({"key": {**KEY, "owner": "other"}}, ("'key'", "other", "--local")),
    ({"key": "x"}, ("'key'",)),
    ({"parallelism": 0}, ("'parallelism'", "0", "1..64")),
    ({"parallelism": 65}, ("'parallelism'", "65")),
    ({"parallelism": "8"}, ("'parallelism'", "'8'")),
    ({"parallelism": True}, ("'parallelism'", "True")),
    ({"format": "yaml"}, ("'format'", "'yaml'", "text, json")),
    ({"yes": "yes"}, ("'yes'", "'yes'", "true or false")),
    ({"prune": 1}, ("'prune'", "1")),
    ({"tty": None}, ("'tty'",)),
    ({"color": "no"}, ("'color'",)),
]


@pytest.mark.parametrize(("change", "words"), REFUSED, ids=[str(c) for c, _ in REFUSED])
def test_a_bad_field_is_refused_by_name(change: dict[str, Any], words: tuple[str, ...]) -> None:
    with pytest.raises(RequestError) as caught:
        parse_request({"request": {**GOOD, **change}}, KEY)
    message = str(caught.value)
    assert all(word in message for word in words), message
    assert caught.value.exit_code == 2


@pytest.mark.parametrize("message", [{}, {"request": []}, {"answer": "yes"}])
def test_not_a_request(message: dict[str, Any]) -> None:
    with pytest.raises(RequestError, match="not a request"):
        parse_request(message, KEY)
