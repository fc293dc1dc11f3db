"""Mosquitto: render a minimal ``mosquitto.conf`` from validated values, and its command line.

Pure functions over a frozen dataclass, reused by the Mosquitto driver. The broker listens on one
address and port, keeps nothing on disk (persistence off) and logs to a file. Anonymous clients
are allowed for now (credentials come with the security issue).
"""

from __future__ import annotations

import getpass
from dataclasses import dataclass
from pathlib import Path

from engine.values import check_host, check_path, check_port, check_user


@dataclass(frozen=True)
class MosquittoConfig:
    """One Mosquitto broker. ``run_as`` matters only when started as root: Mosquitto then
    switches to this user (default: its own ``mosquitto`` user, which cannot write our files)."""

    host: str
    port: int
    log_file: Path
    run_as: str | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "host", check_host("host", self.host))
        check_port("port", self.port)
        object.__setattr__(self, "log_file", check_path("log_file", self.log_file, forbid="\t"))
        if self.run_as is not None:
            check_user("run_as", self.run_as)


def render_mosquitto_conf(cfg: MosquittoConfig) -> str:
    """The ``mosquitto.conf`` text for ``cfg`` (a pure function)."""
    lines = [
        "# Rendered by plantkg; edits are overwritten.",
        "per_listener_settings false",
        f"listener {cfg.port} {cfg.host}",
        "allow_anonymous true",
        "persistence false",
        f"log_dest file {cfg.log_file}",
        "log_type error",
        "log_type warning",
        "log_type notice",
        "log_type information",
        "log_timestamp true",
        "connection_messages true",
    ]
    if cfg.run_as is not None:
        lines.append(f"user {cfg.run_as}")
    return "\n".join(lines) + "\n"


def default_run_as() -> str:
    """The user this process runs as: a root-started broker stays able to write our files."""
    return getpass.getuser()


def mosquitto_command(mosquitto: Path, conf_file: Path) -> list[str]:
    """argv that runs Mosquitto in the foreground with ``conf_file``."""
    check_path("conf_file", conf_file)
    return [str(mosquitto), "-c", str(conf_file)]
