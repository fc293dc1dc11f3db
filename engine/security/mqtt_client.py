"""What one of plantkg's MQTT clients sends a broker to log in (docs/security.md).

A Mosquitto broker plantkg deploys takes plantkg's principals whether it is closed or open (an
open broker without a password file ignores a user name and password), so plantkg's clients
always log in to a Mosquitto: the agent, the bridges and workers, ``check``, the dashboard, the
demo. Another MQTT broker kind (a plugin's) gets no credentials: plantkg renders no users there.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from engine.security import ca, principal_key

#: Broker kinds whose brokers plantkg gives users (their drivers render password files).
USER_KINDS = frozenset({"mosquitto"})


@dataclass(frozen=True)
class MqttLogin:
    """A user name and its password (repr hides the password)."""

    username: str
    password: str

    def __repr__(self) -> str:
        return f"MqttLogin(username={self.username!r}, password=<hidden>)"


def principal_login(kind: str, principal: str, key_path: Path | None = None) -> MqttLogin | None:
    """The login of plantkg principal ``principal`` at a broker of ``kind``; None where plantkg
    renders no users (the client connects anonymously)."""
    if kind not in USER_KINDS:
        return None
    return MqttLogin(principal, principal_key.password_for(principal, key_path))


def apply_login(client: Any, login: MqttLogin | None) -> None:
    """Set ``login`` on a paho client (nothing for None)."""
    if login is not None:
        client.username_pw_set(login.username, login.password)


def apply_tls(client: Any, tls: bool, ca_file: Path | None = None) -> None:
    """For a broker whose listener speaks TLS: TLS on a paho client, verifying the broker's
    certificate (and its IP address) against the plant CA (``ca_file``, default the CA folder's
    ``ca.pem``). Nothing for a plain broker."""
    if tls:
        client.tls_set(ca_certs=str(ca_file or ca.ca_cert_file()))


def secure(client: Any, kind: str, principal: str, tls: bool) -> None:
    """Log ``client`` in as plantkg principal ``principal`` at a broker of ``kind``, with TLS if
    the broker speaks it: what every one of plantkg's own MQTT clients does before connecting."""
    apply_tls(client, tls)
    apply_login(client, principal_login(kind, principal))
