"""The plant's principal key, and the passwords of plantkg's principals derived from it.

One random key (32 bytes, hex, a file of mode 0600) per plant. A principal's password is
``base64url(HMAC-SHA256(key, "plantkg principal password" NUL name))``: every machine holding the
key computes the same password for the same principal, so an agent renders a broker's password
file, another agent's Mosquitto bridge logs in there, and ``plantkg check`` taps it, without any
password ever being sent, planned or stored in a spec. Whoever holds the key can act as any of
plantkg's principals: it is as secret as the agents' tokens.

Where the key is: ``--principal-key FILE`` of ``plantkg agent`` (exported to its brokers and
workers as ``$PLANTKG_PRINCIPAL_KEY``), else ``$PLANTKG_PRINCIPAL_KEY``, else
``$XDG_STATE_HOME/plantkg/principal-key`` (``~/.local/state/...``). The first process that needs
it creates it; on a plant of several machines, copy the file to each (as the agents file's
tokens). Rotating it: replace the file everywhere, restart the agents, ``plantkg apply``.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import secrets
import stat
from collections.abc import Mapping
from pathlib import Path

from engine.errors import EngineError
from engine.security.locations import state_path
from engine.whole_file import create_once

KEY_ENV = "PLANTKG_PRINCIPAL_KEY"
KEY_BYTES = 32
_CONTEXT = b"plantkg principal password\0"


class PrincipalKeyError(EngineError):
    """The principal key file is unusable (unreadable, malformed, readable by others)."""


def key_file(explicit: Path | None = None, environ: Mapping[str, str] | None = None) -> Path:
    """The key file: ``explicit``, else ``$PLANTKG_PRINCIPAL_KEY``, else
    ``$XDG_STATE_HOME/plantkg/principal-key``."""
    return state_path("principal-key", KEY_ENV, explicit, environ)


def load_key(path: Path) -> bytes:
    """The key in ``path``: 64 hex digits, the file readable by its owner only."""
    try:
        mode = stat.S_IMODE(path.stat().st_mode)
        text = path.read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise PrincipalKeyError(f"cannot read the principal key {path}: {exc}",
                                hint="copy the plant's principal-key file there (mode 0600), or "
                                     "delete it on a one-machine plant to get a new one") from None
    if mode & 0o077:
        raise PrincipalKeyError(f"the principal key {path} is readable by others (mode {mode:o})",
                                hint=f"chmod 600 {path}")
    try:
        key = bytes.fromhex(text)
    except ValueError:
        key = b""
    if len(key) != KEY_BYTES:
        raise PrincipalKeyError(f"{path}: not a principal key ({KEY_BYTES * 2} hex digits)",
                                hint="copy the plant's principal-key file there, or delete it to get a new one")
    return key


def load_or_create_key(path: Path) -> bytes:
    """The key in ``path``; a new random one (mode 0600, its folder 0700 if new) if absent. The
    file appears whole (written aside, then hard-linked), so two processes starting together
    read the same key."""
    if path.exists():
        return load_key(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        create_once(path, secrets.token_hex(KEY_BYTES) + "\n", mode=0o600)
    except OSError as exc:
        raise PrincipalKeyError(f"cannot create the principal key {path}: {exc.strerror}",
                                hint="give a path in an existing, writable folder") from None
    return load_key(path)


def principal_password(key: bytes, name: str) -> str:
    """The password of principal ``name`` under ``key`` (43 URL-safe base64 characters)."""
    digest = hmac.new(key, _CONTEXT + name.encode("utf-8"), hashlib.sha256).digest()
    return base64.urlsafe_b64encode(digest).decode("ascii").rstrip("=")


def password_for(name: str, path: Path | None = None) -> str:
    """The password of principal ``name`` on this machine (the key loaded, or created)."""
    return principal_password(load_or_create_key(key_file(path)), name)
