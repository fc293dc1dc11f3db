"""Reading a secret from where its reference says, on this machine (docs/security.md).

A reference is ``env:NAME`` (an environment variable of this process) or ``file:/absolute/path``
(the file's text without one trailing newline). The value is one line of text; every error names
the field and the reference, never the secret.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path

from engine.errors import ConfigValueError
from engine.values import check_secret_ref


def read_secret(field: str, ref: object, environ: Mapping[str, str] | None = None) -> str:
    """The secret ``ref`` points to. Missing, empty, unreadable, not UTF-8, or holding a NUL or a
    line break: a ConfigValueError naming ``field`` and the reference."""
    ref = check_secret_ref(field, ref)
    kind, _, where = ref.partition(":")
    if kind == "plantkg":
        raise ConfigValueError(field, ref, "a principal's password is derived from the principal "
                               "key (engine.security.principal_key), not read from a reference")
    if kind == "env":
        value = (os.environ if environ is None else environ).get(where)
        if value is None:
            raise ConfigValueError(field, ref, f"the environment variable {where} is not set for "
                                   "the process that needs it on this machine; set it where that "
                                   "process starts")
    else:
        try:
            raw = Path(where).read_bytes()
        except OSError as exc:
            raise ConfigValueError(field, ref, f"cannot read the file ({exc.strerror}); create "
                                   "it on this machine, readable by the process that needs it") from None
        try:
            value = raw.decode("utf-8")
        except UnicodeDecodeError:
            raise ConfigValueError(field, ref, "the file is not UTF-8 text") from None
        value = value[:-2] if value.endswith("\r\n") else value.removesuffix("\n")
    if not value:
        raise ConfigValueError(field, ref, "the secret is empty; put the password there")
    if "\0" in value or "\n" in value or "\r" in value:
        raise ConfigValueError(field, ref, "the secret holds a NUL or a line break; a password "
                               "is one line of text")
    return value
