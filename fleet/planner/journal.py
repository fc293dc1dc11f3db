"""The planner's write-ahead log: ``<data-dir>/journal.jsonl``, one JSON object a line, each line
written and fsync'd before the planner acts on it (sends an order, answers an API call).

Records (``seq`` counts lines from 1):

- ``{"seq", "kind": "job", "job", "tasks": [LoTLan task names], "at"}`` — a job was started;
- ``{"seq", "kind": "task", "task": Task.to_json(), "note"}`` — a task after one transition (the
  last record of a task id is its state);
- ``{"seq", "kind": "event", "event", "value", "number", "at"}`` — an event fired (``number`` counts
  events from 1: the windows of TriggeredBy / FinishedBy, fleet/planner/model.py).

A planner killed (kill -9) mid-write leaves at most a torn last line: :func:`replay` drops it
(and :class:`Journal` cuts it off before appending), logging that it did; a bad line anywhere else
is a :class:`JournalError` naming the line, since the log cannot be trusted after it. One planner
per data directory: :class:`Journal` holds an exclusive ``flock`` on ``journal.lock`` (released by
the kernel when the process dies, so a restart after kill -9 is never blocked).
"""

from __future__ import annotations

import fcntl
import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from engine.whole_file import fsync_dir
from fleet.planner.errors import JournalError
from fleet.planner.model import Task

log = logging.getLogger("fleet.planner")
NAME = "journal.jsonl"


@dataclass
class Replayed:
    """What the journal says: every task's last state, the events, the jobs, the next seq."""

    tasks: dict[str, Task] = field(default_factory=dict)
    events: list[dict[str, Any]] = field(default_factory=list)
    jobs: dict[str, list[str]] = field(default_factory=dict)
    seq: int = 0
    good_bytes: int = 0
    torn: bool = False


def replay(path: Path) -> Replayed:
    out = Replayed()
    if not path.exists():
        return out
    data = path.read_bytes()
    lines = data.split(b"\n")
    offset = 0
    for number, raw in enumerate(lines, start=1):
        last = number == len(lines)
        if last and raw == b"":
            break
        try:
            if last:  # no newline after it: written only in part
                raise ValueError("no end of line")
            record = json.loads(raw)
            _apply(out, record)
        except (ValueError, KeyError, TypeError) as exc:
            if last:
                out.torn = True
                log.warning("%s: line %d was written only in part (%s); dropped", path, number, exc)
                break
            raise JournalError(f"{path}: line {number} is not a journal record: {exc}",
                               hint="the journal is damaged; move it aside to start without history") from None
        offset += len(raw) + 1
    out.good_bytes = offset
    return out


def _apply(out: Replayed, record: dict[str, Any]) -> None:
    kind = record["kind"]
    out.seq = int(record["seq"])
    if kind == "task":
        task = Task.from_json(record["task"])
        out.tasks[task.id] = task
    elif kind == "event":
        out.events.append({"number": int(record["number"]), "event": str(record["event"]),
                           "value": record["value"], "at": record.get("at", "")})
    elif kind == "job":
        out.jobs[str(record["job"])] = [str(t) for t in record["tasks"]]
    else:
        raise ValueError(f"unknown kind {kind!r}")


class Journal:
    """Appends records durably; one per planner process and data directory."""

    def __init__(self, data_dir: Path) -> None:
        data_dir.mkdir(parents=True, exist_ok=True)
        self.path = data_dir / NAME
        self._lock = open(data_dir / "journal.lock", "a+b")  # noqa: SIM115 - held for the process's life
        try:
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self._lock.close()
            raise JournalError(f"{data_dir} is used by another planner (journal.lock is held)",
                               hint="stop the other planner or give this one another --data-dir") from None
        self.state = replay(self.path)
        self._file = open(self.path, "ab")  # noqa: SIM115
        if self.state.torn:
            self._file.truncate(self.state.good_bytes)
            os.fsync(self._file.fileno())
        self.seq = self.state.seq
        fsync_dir(data_dir)

    def append(self, kind: str, **fields: Any) -> int:
        self.seq += 1
        line = json.dumps({"seq": self.seq, "kind": kind, **fields}, separators=(",", ":")) + "\n"
        self._file.write(line.encode("utf-8"))
        self._file.flush()
        os.fsync(self._file.fileno())
        return self.seq

    def task(self, task: Task, note: str) -> int:
        return self.append("task", task=task.to_json(), note=note)

    def close(self) -> None:
        self._file.close()
        self._lock.close()
