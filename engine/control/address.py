"""Where ``plantkg serve`` listens for the commands of its user: one Unix socket per served plant.

The socket's name is a digest of what makes two runs the same plant: the files (resolved paths, in
the order given), the agents file (``--agents``, else ``$PLANTKG_AGENTS``; the default when
neither) and the owner. A command and a server that agree on all three meet at the same path;
any difference and the command runs alone. Standard library only: the command imports this
before anything else.
"""

from __future__ import annotations

import hashlib
import json
import os
from collections.abc import Sequence

TYPE_CHECKING = False  # pathlib and typing are not imported on the command's side
if TYPE_CHECKING:
    from pathlib import Path

#: ``sun_path`` holds 108 bytes on Linux (104 on the BSDs); a longer path cannot be bound.
MAX_SOCKET_PATH = 100


def run_folder() -> str:
    """``$PLANTKG_RUN_DIR``, else ``$XDG_RUNTIME_DIR/plantkg``, else ``$XDG_STATE_HOME/plantkg/run``
    (``~/.local/state/plantkg/run``)."""
    explicit = os.environ.get("PLANTKG_RUN_DIR")
    if explicit:
        return os.path.expanduser(explicit)
    runtime = os.environ.get("XDG_RUNTIME_DIR")
    if runtime:
        return os.path.join(runtime, "plantkg")
    base = os.environ.get("XDG_STATE_HOME") or os.path.expanduser("~/.local/state")
    return os.path.join(base, "plantkg", "run")


def _resolved(name: str | os.PathLike[str]) -> str:
    return os.path.realpath(os.path.expanduser(os.fspath(name)))


def plant_key(files: Sequence[str], agents_file: str | os.PathLike[str] | None, owner: str | None) -> dict[str, object]:
    """What names one served plant: resolved files, agents file (None: the default), owner."""
    agents = agents_file or os.environ.get("PLANTKG_AGENTS") or None
    return {"files": [_resolved(f) for f in files], "agents": _resolved(agents) if agents else None,
            "owner": owner}


def socket_file(files: Sequence[str], agents_file: str | os.PathLike[str] | None, owner: str | None) -> str:
    """The socket of the server of that plant (which may not run), as the command connects to it."""
    digest = hashlib.sha256(json.dumps(plant_key(files, agents_file, owner), sort_keys=True).encode())
    return os.path.join(run_folder(), f"serve-{digest.hexdigest()[:24]}.sock")


def run_dir() -> Path:
    """:func:`run_folder` as a Path (the server's side)."""
    from pathlib import Path  # noqa: PLC0415

    return Path(run_folder())


def socket_path(files: Sequence[str], agents_file: str | os.PathLike[str] | None, owner: str | None) -> Path:
    """:func:`socket_file` as a Path (the server's side)."""
    from pathlib import Path  # noqa: PLC0415

    return Path(socket_file(files, agents_file, owner))
