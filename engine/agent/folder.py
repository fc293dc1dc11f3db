"""One broker's folder on the agent: ``<state-dir>/brokers/<id>/``.

::

    spec.json        the BrokerSpec last PUT (its presence means "this broker should run")
    pid.json         pid, start time (clock ticks since boot), argv, restarts, config hash, essence
    topics.json      topics the agent was asked for (reported for implicit-topic drivers: MQTT)
    bridges.json     the native bridges the broker carries (rendered into its config)
    <rendered>       the driver's config files (mosquitto.conf, server.properties, ...)
    data/            the broker's data (Kafka log dirs)
    logs/<kind>.log  the broker's stdout and stderr (and Mosquitto's own log)

Files are written atomically (temporary file + rename), so a crash never leaves half a JSON file.
The agent is the only writer of the folder: it keeps ``topics.json`` and ``bridges.json`` in
memory as last read or written (an edit by hand is seen after the agent restarts).
Rendered files are mode 0600 (:data:`RENDERED_MODE`): they may hold password hashes.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from collections.abc import Callable
from typing import Any, TypeVar

from engine.agent.wire import (
    WireError,
    bridge_spec_from_json,
    broker_spec_from_json,
    observed_topic_from_json,
)
from engine.errors import EngineError
from engine.model import BridgeSpec, BrokerSpec, ObservedTopic, to_dict
from engine.whole_file import write_whole

T = TypeVar("T")

SPEC_FILE = "spec.json"
PID_FILE = "pid.json"
TOPICS_FILE = "topics.json"
BRIDGES_FILE = "bridges.json"
#: Rendered files hold hashes of broker passwords (Mosquitto's password file): only the agent's
#: user reads them, and the broker it starts, which runs as that user (Mosquitto's ``user`` line).
RENDERED_MODE = 0o600


@dataclass(frozen=True)
class PidRecord:
    """What pid.json holds about the running process."""

    pid: int
    start_ticks: int
    argv: tuple[str, ...]
    restarts: int = 0
    config_hash: str | None = None
    essence: dict[str, Any] = field(default_factory=dict)


def write_atomic(path: Path, text: str, mode: int = 0o644) -> None:
    """Write ``path`` whole or not at all (``engine.whole_file.write_whole``)."""
    write_whole(path, text, mode)


class BrokerFolder:
    """Reads and writes the files of one broker folder."""

    def __init__(self, path: Path) -> None:
        self.path = path
        # topics.json and bridges.json as last read or written: the agent is their only writer,
        # and every GET /v1/brokers read them for every broker (100 file reads per observe).
        self._kept: dict[str, Any] = {}

    def forget(self) -> None:
        """Drop what is kept of the files (the folder was moved away or made anew)."""
        self._kept.clear()

    def write_json(self, name: str, data: Any) -> None:
        write_atomic(self.path / name, json.dumps(data, indent=2, sort_keys=True) + "\n")

    def _read_json(self, name: str) -> Any | None:
        path = self.path / name
        try:
            return json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            return None
        except (OSError, ValueError) as exc:
            raise EngineError(f"{path}: unreadable ({exc})",
                              hint="delete the file; the agent rewrites it on the next PUT") from exc

    def read_parsed(self, name: str, parse: Callable[[Any], T], hint: str) -> T | None:
        """File ``name`` parsed by ``parse`` (None if absent); a body that does not parse is an
        EngineError naming the file."""
        data = self._read_json(name)
        if data is None:
            return None
        try:
            return parse(data)
        except WireError as exc:
            raise EngineError(f"{self.path / name}: {exc.message}", hint=hint) from exc

    # spec.json
    def read_spec(self) -> BrokerSpec | None:
        return self.read_parsed(SPEC_FILE, broker_spec_from_json,
                                "PUT the broker again, or delete its folder")

    def write_spec(self, spec: BrokerSpec) -> None:
        self.write_json(SPEC_FILE, to_dict(spec))

    # pid.json
    def read_pid(self) -> PidRecord | None:
        data = self._read_json(PID_FILE)
        if not isinstance(data, dict):
            return None
        try:
            return PidRecord(
                pid=int(data["pid"]), start_ticks=int(data["start_ticks"]),
                argv=tuple(data["argv"]), restarts=int(data.get("restarts", 0)),
                config_hash=data.get("config_hash"), essence=dict(data.get("essence", {})),
            )
        except (KeyError, TypeError, ValueError):
            return None

    def write_pid(self, record: PidRecord) -> None:
        self.write_json(PID_FILE, {
            "pid": record.pid, "start_ticks": record.start_ticks, "argv": list(record.argv),
            "restarts": record.restarts, "config_hash": record.config_hash,
            "essence": record.essence,
        })

    def remove_pid(self) -> None:
        (self.path / PID_FILE).unlink(missing_ok=True)

    # topics.json
    def read_topics(self) -> list[ObservedTopic]:
        if TOPICS_FILE not in self._kept:
            data = self._read_json(TOPICS_FILE) or []
            self._kept[TOPICS_FILE] = tuple(observed_topic_from_json(t) for t in data)
        return list(self._kept[TOPICS_FILE])

    def write_topics(self, topics: list[ObservedTopic]) -> None:
        ordered = tuple(sorted(topics, key=lambda t: t.name))
        self._kept.pop(TOPICS_FILE, None)
        self.write_json(TOPICS_FILE, [to_dict(t) for t in ordered])
        self._kept[TOPICS_FILE] = ordered

    # bridges.json
    def read_bridges(self) -> tuple[BridgeSpec, ...]:
        if BRIDGES_FILE not in self._kept:
            self._kept[BRIDGES_FILE] = self.read_parsed(
                BRIDGES_FILE, lambda data: tuple(bridge_spec_from_json(b) for b in data),
                "PUT the bridges again, or delete the file") or ()
        return self._kept[BRIDGES_FILE]

    def write_bridges(self, bridges: tuple[BridgeSpec, ...]) -> None:
        self._kept.pop(BRIDGES_FILE, None)
        self.write_json(BRIDGES_FILE, [to_dict(b) for b in bridges])
        self._kept[BRIDGES_FILE] = tuple(bridges)

    # rendered files
    def write_rendered(self, files: dict[str, str]) -> None:
        for name, text in files.items():
            # A plain file name in this folder (no path, no symlink followed: the file is written
            # aside and renamed over the name), and none of the agent's own files.
            if not name or "/" in name or "\0" in name or name in (".", "..") \
                    or name in (SPEC_FILE, PID_FILE, TOPICS_FILE, BRIDGES_FILE):
                raise EngineError(f"driver tried to write {name!r} outside its config files",
                                  hint="fix the driver's render_config")
            write_atomic(self.path / name, text, RENDERED_MODE)
