"""Validation of the values that go into rendered config files.

A value that could break or inject into a config file (a newline, a non-numeric port, a host name
where an address belongs, a relative path) is refused here, before rendering, with a
:class:`engine.errors.ConfigValueError` naming the field. The shapes refuse the same values earlier;
this is the driver-side second check the design asks for.
"""

from __future__ import annotations

import ipaddress
import re
from pathlib import Path

from engine.errors import ConfigValueError

#: Characters no rendered path may contain: line breaks end a config line, NUL ends a C string,
#: a backslash is an escape in Java .properties files.
FORBIDDEN_PATH_CHARS = ("\n", "\r", "\0", "\\")


def check_port(field: str, value: object) -> int:
    """A TCP port: an int (not a bool, not a string) in 1..65535."""
    if isinstance(value, bool) or not isinstance(value, int):
        raise ConfigValueError(field, value, "a port must be an integer")
    if not 1 <= value <= 65535:
        raise ConfigValueError(field, value, "a port must be in 1..65535")
    return value


def check_host(field: str, value: object) -> str:
    """An IPv4 or IPv6 address (no host names: a broker binds to an address), normalised."""
    if not isinstance(value, str):
        raise ConfigValueError(field, value, "an IP address must be a string")
    try:
        return str(ipaddress.ip_address(value))
    except ValueError:
        raise ConfigValueError(field, value, "not an IPv4 or IPv6 address") from None


def check_path(field: str, value: object, *, forbid: str = "") -> Path:
    """An absolute path: no line break, NUL, backslash, outer blank, nor a character of ``forbid``."""
    if not isinstance(value, (str, Path)):
        raise ConfigValueError(field, value, "a path must be a string or Path")
    text = str(value)
    bad = [c for c in (*FORBIDDEN_PATH_CHARS, *forbid) if c in text]
    if bad:
        raise ConfigValueError(field, value, f"a path must not contain {bad[0]!r}")
    if text != text.strip():
        raise ConfigValueError(field, value, "a path must not start or end with whitespace")
    path = Path(text)
    if not path.is_absolute():
        raise ConfigValueError(field, value, "the path must be absolute")
    return path


_USER = re.compile(r"[a-z_][a-z0-9_.-]{0,31}")


def check_user(field: str, value: object) -> str:
    """A POSIX user name (lower case letters, digits, ``_ . -``; at most 32 characters)."""
    if not isinstance(value, str) or not _USER.fullmatch(value):
        raise ConfigValueError(field, value, "not a user name")
    return value


def host_in_url(host: str) -> str:
    """``host`` as it appears in ``PROTOCOL://host:port`` (IPv6 in brackets)."""
    return f"[{host}]" if ipaddress.ip_address(host).version == 6 else host


def check_address(field: str, value: object) -> tuple[str, int]:
    """``host:port`` (an IPv6 host in brackets): the normalised address and the port."""
    if not isinstance(value, str) or ":" not in value:
        raise ConfigValueError(field, value, "expected 'host:port' (an IPv6 address in brackets)")
    host, _, port = value.rpartition(":")
    bare = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    if not port.isdigit() or (":" in bare and not host.startswith("[")):
        raise ConfigValueError(field, value, "expected 'host:port' (an IPv6 address in brackets)")
    return check_host(field, bare), check_port(field, int(port))


#: Orion's identifier rules (entity ids and types): 1 to 256 printable ASCII characters, none of
#: ``< > " ' = ; ( )`` (forbidden everywhere) nor ``& ? / #`` (forbidden in identifiers), no blank.
NGSI_ID_MAX = 256
_NGSI_FORBIDDEN = frozenset('<>"\'=;()&?/#')


def check_ngsi_id(field: str, value: object) -> str:
    """An NGSI-v2 entity id or type as Orion accepts it (see ``NGSI_ID_MAX``)."""
    if not isinstance(value, str):
        raise ConfigValueError(field, value, "an NGSI identifier must be a string")
    if not 1 <= len(value) <= NGSI_ID_MAX:
        raise ConfigValueError(field, value, f"an NGSI identifier has 1 to {NGSI_ID_MAX} characters")
    bad = next((c for c in value if not "!" <= c <= "~" or c in _NGSI_FORBIDDEN), None)
    if bad is not None:
        raise ConfigValueError(field, value, f"an NGSI identifier must not contain {bad!r} (only "
                               "printable ASCII without blanks and < > \" ' = ; ( ) & ? / #)")
    return value


#: Where a secret is, never the secret: an environment variable or an absolute file path of the
#: machine that reads it (docs/security.md); ``plantkg:principal-key`` for plantkg's own
#: principals, whose passwords derive from the plant's principal key (engine.security).
SECRET_REF = re.compile(r"env:[A-Za-z_][A-Za-z0-9_]{0,127}|file:/[^\s\x00-\x1f\x7f\\]{1,4095}"
                        r"|plantkg:principal-key")
#: A broker user name: a resource's pk:id (one word of a password or ACL file: no ':' or blank).
BROKER_USER = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.-]{0,127}")


def check_secret_ref(field: str, value: object) -> str:
    """``env:NAME``, ``file:/absolute/path`` or ``plantkg:principal-key``: a reference to a
    secret, not a secret."""
    if not isinstance(value, str) or not SECRET_REF.fullmatch(value):
        shown = (value if isinstance(value, str) and value.startswith(("env:", "file:", "plantkg:"))
                 else "(not shown)")
        raise ConfigValueError(field, shown, "must be env:NAME or file:/absolute/path, where the "
                               "secret is on the broker's machine; never the secret itself")
    return value


def check_broker_user(field: str, value: object) -> str:
    """A user name for a broker's password and ACL files."""
    if not isinstance(value, str) or not BROKER_USER.fullmatch(value):
        raise ConfigValueError(field, value, "a user name is 1 to 128 of A-Z a-z 0-9 _ . - "
                               "starting with a letter, a digit or _")
    return value
