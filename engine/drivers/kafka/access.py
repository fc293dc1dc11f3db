"""A closed Kafka (issue 13): SASL/SCRAM users and ACLs from ``BrokerSpec.users``.

A Kafka broker one of whose clients has a ``pk:secretRef`` has users (engine.derived.access): it is
rendered closed (engine.drivers.kafka.runtime: SASL_PLAINTEXT on every listener, KRaft's
StandardAuthorizer, nothing allowed without an ACL), and once it answers the driver makes its
users and ACLs exactly what the spec says (:func:`sync_access`):

- each user gets a SCRAM-SHA-512 credential with the password its ``secret_ref`` points to on
  this machine (resolved here, never sent anywhere else); a SCRAM user the spec does not name is
  deleted;
- its ACLs: WRITE and DESCRIBE on each topic it may write, READ and DESCRIBE on each topic it may
  read, READ on every consumer group if it reads anything (a group name is the client's choice);
  every other ACL on the broker is deleted (plantkg owns the broker's ACLs).

plantkg's own principal, ``plantkg``, is a super user authenticated with SASL/PLAIN; its password is
derived from the broker's agent token (:func:`engine.derived.access.kafka_internal_password`): the driver
reads the token file of the agent it runs in, and a bridge worker on another machine gets the
derived password with its PUT, like a context broker's token.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import secrets
from collections.abc import Iterable
from pathlib import Path
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

from engine.derived.access import kafka_internal_password
from engine.drivers.base import AGENT_TOKEN_FILE_ENV, resolve_secret
from engine.drivers.kafka.runtime import INTERNAL_USER
from engine.drivers.kafka.topics import result
from engine.errors import ConfigValueError
from engine.model import BrokerSpec, BrokerUser

#: A digest of the users' passwords, rendered beside server.properties: a changed password
#: changes the rendering, so the agent restarts the broker and the credentials are set again.
DIGEST_FILE = "scram.digest"
SCRAM_ITERATIONS = 8192
_ALL_ACLS = AclBindingFilter(ResourceType.ANY, None, ResourcePatternType.ANY, None, None,
                             AclOperation.ANY, AclPermissionType.ANY)


def is_closed(spec: BrokerSpec) -> bool:
    """A Kafka with users admits nobody else (Kafka has no anonymous clients beside SASL ones)."""
    return bool(spec.users)


def token_file(broker_dir: Path | None = None) -> Path:
    """The agent's token file: ``$PLANTKG_AGENT_TOKEN_FILE`` (set by ``plantkg agent``), else
    ``<state dir>/token`` beside the broker folders."""
    configured = os.environ.get(AGENT_TOKEN_FILE_ENV)
    if configured:
        return Path(configured)
    if broker_dir is None:
        raise ConfigValueError(AGENT_TOKEN_FILE_ENV, None, "unset: a closed Kafka needs its agent's "
                               "token to derive plantkg's own password; run it under `plantkg agent`")
    return broker_dir.parent.parent / "token"


def internal_password(broker_dir: Path | None = None) -> str:
    """plantkg's own password on this machine's closed Kafka brokers."""
    path = token_file(broker_dir)
    try:
        token = path.read_text(encoding="utf-8").strip()
    except OSError as exc:
        raise ConfigValueError("token_file", str(path), f"cannot be read ({exc.strerror}): a closed Kafka "
                               "derives plantkg's own password from its agent's token") from None
    return kafka_internal_password(token)


def client_config(password: str) -> dict[str, Any]:
    """librdkafka settings of a plantkg client of a closed Kafka."""
    return {"security.protocol": "SASL_PLAINTEXT", "sasl.mechanism": "PLAIN",
            "sasl.username": INTERNAL_USER, "sasl.password": password}


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
