"""A closed Kafka (issue 13): SASL/SCRAM users and ACLs from ``BrokerSpec.users``.

A Kafka broker of its own is closed unless the plant says ``pk:allowAnonymous true``
(engine.derived.access), with or without users: it is rendered closed (engine.drivers.kafka.runtime: SASL_PLAINTEXT on every listener, KRaft's
StandardAuthorizer, nothing allowed without an ACL), and once it answers the driver makes its
users and ACLs exactly what the spec says (:func:`sync_access`):

- each user gets a SCRAM-SHA-512 credential with the password its ``secret_ref`` points to on
  this machine (resolved here, never sent anywhere else); a SCRAM user the spec does not name is
  deleted;
- its ACLs: WRITE and DESCRIBE on each topic it may write, READ and DESCRIBE on each topic it may
  read, READ on every consumer group if it reads anything (a group name is the client's choice);
  every other ACL on the broker is deleted (plantkg owns the broker's ACLs).

plantkg's own principal, ``plantkg``, is a super user authenticated with SASL/PLAIN; its password is
derived from the plant's principal key (engine.security.kafka_client), so the driver, the bridge
workers, ``plantkg check``, the dashboard and the demo compute the same one wherever they run.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
from collections.abc import Iterable
from typing import Any

from confluent_kafka.admin import (
    AclBinding,
    AclBindingFilter,
    AclOperation,
    AclPermissionType,
    AdminClient,
    ResourcePatternType,
    ResourceType,
    ScramCredentialInfo,
    ScramMechanism,
    UserScramCredentialDeletion,
    UserScramCredentialUpsertion,
)

from engine.drivers.base import resolve_secret
from engine.drivers.kafka.topics import result
from engine.model import BrokerSpec, BrokerUser
from engine.security import kafka_client

#: A digest of the users' passwords, rendered beside server.properties: a changed password
#: changes the rendering, so the agent restarts the broker and the credentials are set again.
DIGEST_FILE = "scram.digest"
SCRAM_ITERATIONS = 8192
_ALL_ACLS = AclBindingFilter(ResourceType.ANY, None, ResourcePatternType.ANY, None, None,
                             AclOperation.ANY, AclPermissionType.ANY)


def is_closed(spec: BrokerSpec) -> bool:
    """A Kafka that admits only its users and plantkg (engine.derived.access: closed unless the
    plant says ``pk:allowAnonymous true``; Kafka has no anonymous clients beside SASL ones)."""
    return kafka_client.is_closed(spec)


def internal_password() -> str:
    """plantkg's own password on this machine's closed Kafka brokers (the principal key's)."""
    return kafka_client.password()


def users_digest(users: Iterable[BrokerUser], key: str) -> str:
    """An HMAC (keyed with plantkg's password) over each user's name and password: equal users
    give equal digests, and the digest tells nothing of a password."""
    mac = hmac.new(key.encode(), digestmod=hashlib.sha256)
    for user in sorted(users, key=lambda u: u.name):
        mac.update(user.name.encode() + b"\0" + resolve_secret(user).encode() + b"\0")
    return mac.hexdigest() + "\n"


def wanted_acls(users: Iterable[BrokerUser]) -> set[tuple[Any, ...]]:
    """(resource type, name, pattern, principal, host, operation, permission) for each right."""
    out: set[tuple[Any, ...]] = set()
    for user in users:
        principal = f"User:{user.name}"
        for topic in user.write:
            for op in (AclOperation.WRITE, AclOperation.DESCRIBE):
                out.add((ResourceType.TOPIC, topic, ResourcePatternType.LITERAL, principal, "*", op,
                         AclPermissionType.ALLOW))
        for topic in user.read:
            for op in (AclOperation.READ, AclOperation.DESCRIBE):
                out.add((ResourceType.TOPIC, topic, ResourcePatternType.LITERAL, principal, "*", op,
                         AclPermissionType.ALLOW))
        if user.read:
            out.add((ResourceType.GROUP, "*", ResourcePatternType.LITERAL, principal, "*",
                     AclOperation.READ, AclPermissionType.ALLOW))
    return out


def _key(binding: AclBinding) -> tuple[Any, ...]:
    return (binding.restype, binding.name, binding.resource_pattern_type, binding.principal, binding.host,
            binding.operation, binding.permission_type)


def sync_access(admin: AdminClient, users: tuple[BrokerUser, ...], timeout: float) -> None:
    """Make the broker's SCRAM users and ACLs exactly ``users`` (see the module docstring).
    Raises a DriverError (temporary while the broker is starting) when Kafka refuses or is away."""
    mechanism = ScramCredentialInfo(ScramMechanism.SCRAM_SHA_512, SCRAM_ITERATIONS)
    names = {u.name for u in users}
    present = result(admin.describe_user_scram_credentials(request_timeout=timeout), timeout,
                     "listing the SCRAM users")
    changes: list[Any] = [UserScramCredentialUpsertion(u.name, mechanism, resolve_secret(u).encode(),
                                                       secrets.token_bytes(32)) for u in users]
    changes += [UserScramCredentialDeletion(name, ScramMechanism.SCRAM_SHA_512)
                for name in sorted(set(present) - names)]
    if changes:
        futures = admin.alter_user_scram_credentials(changes, request_timeout=timeout)
        for name in list(futures):
            result(futures[name], timeout, f"setting the SCRAM credential of user {name!r}")
    want = wanted_acls(users)
    have = {_key(b): b for b in result(admin.describe_acls(_ALL_ACLS, request_timeout=timeout), timeout,
                                       "listing the ACLs")}
    missing = [AclBinding(*key) for key in sorted(want - set(have), key=repr)]
    if missing:
        futures = admin.create_acls(missing, request_timeout=timeout)
        for binding in list(futures):
            result(futures[binding], timeout, f"creating the ACL {binding}")
    extra = [AclBindingFilter(*key) for key in sorted(set(have) - want, key=repr)]
    if extra:
        futures = admin.delete_acls(extra, request_timeout=timeout)
        for binding in list(futures):
            result(futures[binding], timeout, f"deleting the ACL {binding}")
