"""Where plantkg keeps the plant's secrets on a machine: an explicit path, else an environment
variable, else ``$XDG_STATE_HOME/plantkg/<name>`` (``~/.local/state`` when unset)."""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path


def state_path(name: str, env_var: str, explicit: Path | None = None,
               environ: Mapping[str, str] | None = None) -> Path:
    """``explicit``, else ``$env_var``, else ``$XDG_STATE_HOME/plantkg/<name>``."""
    env = os.environ if environ is None else environ
    if explicit is not None:
        return Path(explicit)
    if env.get(env_var):
        return Path(env[env_var])
    base = env.get("XDG_STATE_HOME") or str(Path("~/.local/state").expanduser())
    return Path(base) / "plantkg" / name
