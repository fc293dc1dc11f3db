"""The Mosquitto listener that takes client certificates of the plant CA (``cert_port``)."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.drivers.mosquitto.runtime import MosquittoConfig, MosquittoTls, render_mosquitto_conf
from engine.errors import ConfigValueError

TLS = MosquittoTls(Path("/s/ca.pem"), Path("/s/cert.pem"), Path("/s/key.pem"))


def _cfg(**overrides: object) -> MosquittoConfig:
    values: dict[str, object] = {"host": "127.0.0.1", "port": 8883, "log_file": Path("/s/log"), "tls": TLS,
                                 "allow_anonymous": False}
    return MosquittoConfig(**{**values, **overrides})  # type: ignore[arg-type]


def test_a_second_listener_requires_a_certificate_and_takes_its_name() -> None:
    text = render_mosquitto_conf(_cfg(cert_port=8884))
    first, second = text.split("\nlistener 8884 127.0.0.1\n")
    assert "listener 8883 127.0.0.1" in first and "require_certificate" not in first
    block = second.split("\n\n")[0].splitlines()
    assert block[:6] == ["cafile /s/ca.pem", "certfile /s/cert.pem", "keyfile /s/key.pem", "tls_version tlsv1.2",
                         "require_certificate true", "use_identity_as_username true"]


def test_without_it_no_listener_asks_for_a_certificate() -> None:
    text = render_mosquitto_conf(_cfg())
    assert text.count("listener ") == 1 and "require_certificate" not in text and "use_identity" not in text


def test_it_comes_before_the_bridges() -> None:
    """Lines after a ``connection`` belong to that bridge: the listener must precede them."""
    from engine.drivers.mosquitto.runtime import MosquittoBridge, MosquittoBridgeTopic
    bridge = MosquittoBridge(name="b1", remote_host="127.0.0.1", remote_port=1884,
                             topics=(MosquittoBridgeTopic("t", "out"),))
    text = render_mosquitto_conf(_cfg(cert_port=8884, bridges=(bridge,)))
    assert text.index("listener 8884") < text.index("connection b1")


@pytest.mark.parametrize("overrides", [{"cert_port": 8883}, {"cert_port": 8884, "tls": None},
                                       {"cert_port": 0}, {"cert_port": 70000}])
def test_refused(overrides: dict[str, object]) -> None:
    with pytest.raises(ConfigValueError) as caught:
        _cfg(**overrides)
    assert "cert_port" in str(caught.value)
