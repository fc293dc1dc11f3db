"""A closed Kafka cluster's users and ACLs, awaited on every node before apply returns (issue 13).

The lead node's driver sets the users and ACLs once, through an AdminClient
(engine.drivers.kafka.access); the controller writes them to the cluster's metadata log and each
broker applies them from there a moment later. Until it has, a client that logs in at that node
is refused (authentication failed, topic authorization failed) although ``plantkg apply`` said
done. So the lead's agent, before it answers the PUT, polls every broker-role node of the cluster
(``KafkaNode.bootstrap``), each on its own listener (engine.drivers.kafka.wire: an AdminClient
would not ask that node), until each one reports:

1. exactly the SCRAM-SHA-512 users the plant wants (no missing, none left over);
2. exactly the ACLs the plant wants (:func:`engine.drivers.kafka.access.wanted_acls`);
3. and accepts each user's current password (a SCRAM login as that user: a changed password
   shows in no listing).

:func:`differences` (1 and 2) is pure; :func:`wait_every_node` does the polling, within a
deadline, and raises :class:`~engine.errors.AccessNotSpreadError` naming the first node that
still lags and what it lacks. A node alone is not waited for: its broker and controller are one
process, which applies what it just committed within moments (and it was as fast as before).
"""

from __future__ import annotations

import logging
import ssl
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

from confluent_kafka.admin import AclOperation, AclPermissionType, ResourceType

from engine import process
from engine.drivers.base import resolve_secret
from engine.drivers.kafka.access import wanted_acls
from engine.drivers.kafka.wire import AclKey, NodeConnection
from engine.errors import AccessNotSpreadError, BrokerUnavailableError, DriverError, WaitTimeoutError
from engine.model import BrokerUser
from engine.security import https

#: Seconds between two rounds of asking the nodes that lag.
POLL = 0.1

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class NodeAccess:
    """The users (with a SCRAM-SHA-512 credential) and ACLs of one node, or those the plant wants."""

    users: frozenset[str]
    acls: frozenset[AclKey]


def wanted(users: Iterable[BrokerUser]) -> NodeAccess:
    """What every node must report for the plant's ``users`` (Kafka's codes, as on the wire)."""
    users = tuple(users)
    return NodeAccess(frozenset(u.name for u in users), frozenset(_codes(key) for key in wanted_acls(users)))


def _codes(key: tuple[Any, ...]) -> AclKey:
    """A key of :func:`wanted_acls` (confluent-kafka's enums, whose values are Kafka's codes)."""
    rtype, name, pattern, principal, host, operation, permission = key
    return (int(rtype.value), name, int(pattern.value), principal, host, int(operation.value),
            int(permission.value))


def describe_acl(key: AclKey) -> str:
    """``ALLOW User:plc WRITE on TOPIC 'line.energy'`` (the names confluent-kafka gives Kafka's
    codes, for an error)."""
    rtype, name, _pattern, principal, _host, operation, permission = key
    return (f"{_name(AclPermissionType, permission)} {principal} {_name(AclOperation, operation)} "
            f"on {_name(ResourceType, rtype)} {name!r}")


def _name(kind: type[Enum], code: int) -> str | int:
    try:
        return kind(code).name
    except ValueError:  # a code this client does not know: shown as the number
        return code


def differences(want: NodeAccess, seen: NodeAccess) -> tuple[str, ...]:
    """What a node that reports ``seen`` lacks, or still has, of ``want`` (empty: nothing);
    one phrase each, in a stable order."""
    out = [f"lacks user {u!r}" for u in sorted(want.users - seen.users)]
    out += [f"still has user {u!r}" for u in sorted(seen.users - want.users)]
    out += [f"lacks ACL {describe_acl(k)}" for k in sorted(want.acls - seen.acls)]
    out += [f"still has ACL {describe_acl(k)}" for k in sorted(seen.acls - want.acls)]
    return tuple(out)


@dataclass(frozen=True)
class Login:
    """How plantkg reaches the nodes: its own password (SASL/PLAIN) and the plant CA (TLS)."""

    password: str
    user: str = "plantkg"
    ca_file: Path | str | None = None
    timeout: float = 5.0


def node_lag(address: str, users: Sequence[BrokerUser], want: NodeAccess, login: Login,
             secret: Callable[[BrokerUser], str] = resolve_secret,
             tls: ssl.SSLContext | None = None) -> tuple[str, ...]:
    """What the node at ``address`` lacks (empty: it enforces ``want``); a node that does not
    answer, or answers an error, lags by that ("could not be asked (...)")."""
    try:
        with NodeConnection(address, tls=tls, timeout=login.timeout) as conn:
            conn.login_plain(login.user, login.password)
            lag = differences(want, NodeAccess(frozenset(conn.scram_users()), frozenset(conn.acls())))
        if lag:
            return lag
        for user in users:  # each on a connection of its own, as its client would
            with NodeConnection(address, tls=tls, timeout=login.timeout) as conn:
                if not conn.login_scram(user.name, secret(user)):
                    return (f"refuses user {user.name!r}'s password (SCRAM-SHA-512)",)
    except BrokerUnavailableError as exc:
        return (f"could not be asked ({exc.message})",)
    except DriverError as exc:
        return (f"answered with an error ({exc.message})",)
    return ()


def wait_every_node(cluster: str, nodes: Sequence[str], users: Sequence[BrokerUser], login: Login,
                    deadline: float, *, lag: Callable[[str], tuple[str, ...]] | None = None) -> None:
    """Return once every node of ``nodes`` (``host:port``) enforces ``users``; after ``deadline``
    seconds, :class:`AccessNotSpreadError` for the first node that still lags. ``lag``: what a
    node lacks (default :func:`node_lag`; a test passes its own)."""
    began = time.monotonic()
    want = wanted(users)
    tls = None if login.ca_file is None else https.client_context(Path(login.ca_file))  # once per wait
    ask = lag or (lambda node: node_lag(node, users, want, login, tls=tls))
    pending = {node: ("was not asked yet",) for node in nodes}

    def all_caught_up() -> bool:
        for node in list(pending):
            pending[node] = ask(node)
            if not pending[node]:
                del pending[node]
        return not pending

    try:
        process.wait_until(all_caught_up, deadline, POLL, what=f"every node of Kafka cluster {cluster!r}")
    except WaitTimeoutError:
        node = next(iter(pending))
        raise AccessNotSpreadError(cluster, node, pending[node], deadline, others=tuple(pending)[1:]) from None
    log.info("Kafka cluster %s: users and ACLs enforced by its %d node(s) after %.2f s", cluster, len(nodes),
             time.monotonic() - began)
