"""The users of a Mosquitto and what each may do, as the file of Mosquitto's dynamic security plugin.

Why the plugin and not ``password_file`` + ``acl_file``: Mosquitto 2.0's ACL file checks a client
through the ACL list it attached at the client's CONNECT, and a persistent session restored from
the database after a restart has none until its client connects again, so every message that
arrives for it in between is denied and dropped (``security_default.c``: no ``acl_list``, no
patterns: denied; eclipse/mosquitto#1891). A broker killed and restarted by its agent lost 1,750
of 10,000 bridged messages that way (tests/integration/test_bridges.py, the SIGKILL test). The
plugin looks a client up by its user name at each check, and the name is restored with the
session, so queued messages for a client that has not reconnected yet are kept.

:func:`render_dynsec` is pure: the plugin's JSON (``clients``, ``roles``, ``groups``,
``defaultACLAccess``) from validated users and their passwords. A password is stored as the plugin
reads it: PBKDF2-HMAC-SHA512, 101 iterations, a 12-byte salt, both base64 (the same hash as
``mosquitto_passwd``); a user whose password did not change keeps its salt and hash from the
previous file, so the same inputs render the same file and the agent does not restart the broker.

What a user may do: ``publishClientSend`` for each topic it may write, ``publishClientReceive``
for each it may read; subscribing is allowed to all and delivery is filtered (as the ACL file
did: a subscription to a topic one may not read is granted, nothing arrives). A broker that still
admits anonymous clients puts them in an ``anonymous`` group that may publish and receive every
topic and read ``$SYS``. Nobody may use ``$CONTROL/dynamic-security``: the file is the only way
to change the users (plantkg renders it).
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import hmac
import json
import os
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from engine.drivers.mosquitto.runtime import (
    PW_ITERATIONS,
    PW_SALT_BYTES,
    MosquittoUser,
    check_password,
)
from engine.errors import ConfigValueError

DYNSEC_FILE = "dynamic-security.json"
#: The plugin as Debian's ``mosquitto`` package ships it (and other common places).
PLUGIN_FILE = "mosquitto_dynamic_security.so"
ANONYMOUS_GROUP = "anonymous"
_DEFAULT_ACCESS = {"publishClientSend": False, "publishClientReceive": False,
                   "subscribe": True, "unsubscribe": True}
_TYPES = {"read": ("publishClientReceive",), "write": ("publishClientSend",),
          "readwrite": ("publishClientSend", "publishClientReceive")}


def render_dynsec(users: Sequence[MosquittoUser], passwords: Mapping[str, str], previous: str = "",
                  *, anonymous: bool = False,
                  salt: Callable[[], bytes] = lambda: os.urandom(PW_SALT_BYTES)) -> str:
    """The plugin's JSON for ``users`` (each with its password in ``passwords``), sorted by name.
    A certificate user (``certificate``) without a password gets a client without one: it can
    log in only where a client certificate names it (the certificate listener), never with a
    password. ``previous``: the file rendered last time (its matching hashes are kept). Errors
    never show a password."""
    names = [u.name for u in users]
    if len(set(names)) != len(names):
        raise ConfigValueError("users", names, "two users with the same name")
    kept = _previous_hashes(previous)
    clients, roles = [], []
    for user in sorted(users, key=lambda u: u.name):
        password = passwords.get(user.name)
        if password is None and user.certificate:
            stored: dict[str, Any] = {}  # no password: the plugin refuses every password login for it
        else:
            check_password(user.name, password)
            assert password is not None
            stored = kept.get(user.name) or {}
            if not stored or not _matches(stored, password):
                stored = _hash(password, salt())
        clients.append({"username": user.name, **stored, "roles": [{"rolename": user.name}]})
        roles.append({"rolename": user.name, "acls": _acls(user)})
    data: dict[str, Any] = {"defaultACLAccess": _DEFAULT_ACCESS, "clients": clients, "roles": roles,
                            "groups": []}
    if anonymous:
        roles.append({"rolename": ANONYMOUS_GROUP, "acls": [
            {"acltype": kind, "topic": topic, "allow": True}
            for kind, topic in (("publishClientSend", "#"), ("publishClientReceive", "#"),
                                ("publishClientReceive", "$SYS/#"))]})
        data["groups"] = [{"groupname": ANONYMOUS_GROUP, "roles": [{"rolename": ANONYMOUS_GROUP}]}]
        data["anonymousGroup"] = ANONYMOUS_GROUP
    return json.dumps(data, indent=1, sort_keys=True) + "\n"


def _acls(user: MosquittoUser) -> list[dict[str, Any]]:
    write, read = set(user.write), set(user.read)
    grants = [("write", t) for t in sorted(write)] + [("read", t) for t in sorted(read)]
    grants += list(user.filters)
    return [{"acltype": kind, "topic": topic, "allow": True}
            for access, topic in grants for kind in _TYPES[access]]


def _hash(password: str, salt: bytes) -> dict[str, Any]:
    if len(salt) != PW_SALT_BYTES:
        raise ConfigValueError("salt", len(salt), f"must be {PW_SALT_BYTES} bytes")
    digest = hashlib.pbkdf2_hmac("sha512", password.encode("utf-8"), salt, PW_ITERATIONS)
    return {"password": base64.b64encode(digest).decode(), "salt": base64.b64encode(salt).decode(),
            "iterations": PW_ITERATIONS}


def _matches(stored: Mapping[str, Any], password: str) -> bool:
    try:
        salt = base64.b64decode(stored["salt"], validate=True)
        expected = base64.b64decode(stored["password"], validate=True)
        iterations = int(stored["iterations"])
    except (KeyError, TypeError, ValueError, binascii.Error):
        return False
    if not 1 <= iterations <= 1_000_000:
        return False
    digest = hashlib.pbkdf2_hmac("sha512", password.encode("utf-8"), salt, iterations)
    return hmac.compare_digest(digest, expected)


def _previous_hashes(text: str) -> dict[str, dict[str, Any]]:
    """user name -> its stored hash in a previous file (unreadable parts: new hashes)."""
    try:
        data = json.loads(text) if text else {}
    except ValueError:
        return {}
    out = {}
    for client in data.get("clients", []) if isinstance(data, dict) else []:
        if isinstance(client, dict) and isinstance(client.get("username"), str):
            out[client["username"]] = {k: client.get(k) for k in ("password", "salt", "iterations")}
    return out


def matches(text: str, name: str, password: str) -> bool:
    """True if the rendered file ``text`` holds the hash of ``password`` for user ``name``."""
    stored = _previous_hashes(text).get(name)
    return stored is not None and _matches(stored, password)
