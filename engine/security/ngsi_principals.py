"""The principals file of a closed context broker: what the driver renders, what the broker reads.

Shared by the NGSI driver (which reads each principal's token where its ``secret_ref`` says, on
the broker's machine, and writes only its SHA-256 digest) and the context broker
(engine.context_broker.access, which checks requests against it). The file:
``{"principals": [{"name", "sha256", "write": [entity ids], "read": [entity ids]}]}``, 0600.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path


class PrincipalsFileError(Exception):
    """The principals file cannot be used; the message names the file and what is wrong."""


@dataclass(frozen=True)
class Principal:
    """A principal of the context broker: its name, its token's digest, its entities."""

    name: str
    digest: str                    # hex SHA-256 of the token
    write: frozenset[str] = frozenset()
    read: frozenset[str] = frozenset()
    internal: bool = False         # the agent's token: every right


def token_digest(token: str) -> str:
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


def load_principals(path: Path) -> tuple[Principal, ...]:
    """The principals of ``path`` (``{"principals": [{"name", "sha256", "write", "read"}]}``)."""
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as err:
        raise PrincipalsFileError(f"cannot read --principals {path}: {err.strerror}") from None
    except ValueError as err:
        raise PrincipalsFileError(f"--principals {path} is not JSON: {err}") from None
    rows = data.get("principals") if isinstance(data, dict) else None
    if not isinstance(rows, list):
        raise PrincipalsFileError(f"--principals {path}: needs an object with a list 'principals'")
    out = []
    for i, row in enumerate(rows):
        ok = (isinstance(row, dict) and isinstance(row.get("name"), str)
              and isinstance(row.get("sha256"), str) and len(row["sha256"]) == 64
              and all(isinstance(row.get(k), list) and all(isinstance(e, str) for e in row[k])
                      for k in ("write", "read")))
        if not ok:
            raise PrincipalsFileError(f"--principals {path}: principals[{i}] needs a name, a sha256 "
                                      "(64 hex digits) and lists 'write' and 'read' of entity ids")
        out.append(Principal(row["name"], row["sha256"], frozenset(row["write"]), frozenset(row["read"])))
    return tuple(out)


def render_principals(principals: Mapping[str, tuple[str, tuple[str, ...], tuple[str, ...]]]) -> str:
    """The file :func:`load_principals` reads: name -> (token, write ids, read ids). Only the
    tokens' digests are written."""
    rows = [{"name": name, "sha256": token_digest(token), "write": sorted(write), "read": sorted(read)}
            for name, (token, write, read) in sorted(principals.items())]
    return json.dumps({"principals": rows}, indent=1, sort_keys=True) + "\n"
