"""The operator's stop flag of one broker: ``<state-dir>/brokers/<id>/stopped.json``.

``plantkg stop`` (``POST /v1/brokers/<id>/stop``) writes this file *before* it stops the process,
and ``start``/``restart`` remove it. While it exists the agent does not start the broker: not
the supervisor, not a new agent re-adopting its folders (after a restart or a kill -9 it stops a
process it finds there), not a PUT. The file lives in the broker's folder, so the data, the
config and the spec stay exactly where they were.

It also keeps what the broker last reported of its topics (for a driver whose topics are asked
from the running broker: Kafka), so that a stopped broker shows its topics as kept, not missing,
and a plan does not ask to create them again.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

from engine.agent.folder import write_atomic
from engine.agent.wire import WireError, observed_topic_from_json
from engine.errors import EngineError
from engine.model import ObservedTopic, to_dict

HELD_FILE = "stopped.json"


@dataclass(frozen=True)
class Held:
    """Since when (seconds since the epoch) the operator keeps the broker stopped, and the topics
    it had then."""

    since: float
    topics: tuple[ObservedTopic, ...] = ()


def read_held(folder: Path) -> Held | None:
    """The flag of the broker in ``folder`` (None: not stopped by the operator). A file that
    cannot be read still means stopped: the safe reading of a damaged flag."""
    path = folder / HELD_FILE
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        return None
    except (OSError, ValueError):
        return Held(since=0.0)
    if not isinstance(data, dict):
        return Held(since=0.0)
    try:
        topics = tuple(observed_topic_from_json(t) for t in data.get("topics", []))
    except (WireError, TypeError):
        topics = ()
    since = data.get("since")
    return Held(since=float(since) if isinstance(since, (int, float)) else 0.0, topics=topics)


def write_held(folder: Path, topics: list[ObservedTopic] | tuple[ObservedTopic, ...]) -> Held:
    """Mark the broker stopped by the operator (atomically; before its process is stopped)."""
    held = Held(since=time.time(), topics=tuple(sorted(topics, key=lambda t: t.name)))
    try:
        write_atomic(folder / HELD_FILE, json.dumps(
            {"since": held.since, "topics": [to_dict(t) for t in held.topics]},
            indent=2, sort_keys=True) + "\n")
    except OSError as exc:
        raise EngineError(f"{folder / HELD_FILE}: cannot be written ({exc})",
                          hint="check the agent's state directory; the broker was not stopped") \
            from exc
    return held


def clear_held(folder: Path) -> None:
    """The operator starts the broker again: the agent may start it."""
    (folder / HELD_FILE).unlink(missing_ok=True)
