"""Telling a broker to save its state more often than it can by itself (issue 16's safe default).

Mosquitto keeps what it queued for offline persistent sessions (a bridge, a bridge worker, a
subscriber) in memory and writes it to its database only now and then: on its own by whole
seconds (``autosave_interval 1``: every 1-2 s), or when sent SIGUSR1. A SIGKILL loses what it
acknowledged since its last save: 5,042 of 15,000 acknowledged messages for an offline
subscriber, and 1,000 in the double fault worker-then-source-Mosquitto, in
``benchmarks/bench_durability`` with the time save alone; none with a save signal every 0.25 s.

So a driver may ask the agent for a save signal (:class:`engine.drivers.base.PeriodicSave`), and
the agent's supervisor sends it every ``every`` seconds through :class:`SaveTicker`, but only

- to a process that catches the signal (``SigCgt`` in ``/proc/<pid>/status``): a Mosquitto that
  has not installed its handlers yet (just spawned) would be *killed* by SIGUSR1's default action;
- when the process read anything since the last save (``rchar`` in ``/proc/<pid>/io``): an idle
  broker is not rewritten four times a second (every save writes the whole database).

The window this cannot close: what a broker acknowledged in the last ``every`` seconds before a
SIGKILL (Mosquitto has no write-ahead log). If the agent itself dies, the broker's own time save
goes on.
"""

from __future__ import annotations

import os
import signal
from dataclasses import dataclass
from pathlib import Path


def catches(pid: int, sig: signal.Signals) -> bool:
    """Whether process ``pid`` has a handler for ``sig`` (False if it is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("SigCgt:"):
                return bool(int(line.split()[1], 16) >> (int(sig) - 1) & 1)
    except (OSError, ValueError, IndexError):
        return False
    return False


def chars_read(pid: int) -> int | None:
    """Bytes process ``pid`` has read so far, sockets included (None if unknown)."""
    try:
        for line in Path(f"/proc/{pid}/io").read_text().splitlines():
            if line.startswith("rchar:"):
                return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return None


@dataclass
class SaveTicker:
    """When to tell one broker to save: every ``every`` s, if it read anything since the last."""

    every: float
    due: float = 0.0            # monotonic time of the next possible save
    chars: int | None = None    # rchar when the last save signal was sent
    pid: int | None = None      # the process it was sent to (a restarted broker starts afresh)
    sent: int = 0               # signals sent, for status and tests

    def step(self, pid: int, sig: signal.Signals, now: float) -> bool:
        """Send ``sig`` to ``pid`` if a save is due, the process catches the signal and it read
        something since the last save. True if it was sent. The caller makes sure ``pid`` is its
        broker (a spawned child not yet reaped, or an adopted process whose start time matches)."""
        if now < self.due:
            return False
        self.due = now + self.every
        if pid != self.pid:
            self.pid, self.chars = pid, None
        chars = chars_read(pid)
        if chars is not None and chars == self.chars:
            return False
        if not catches(pid, sig):
            return False
        try:
            os.kill(pid, sig)
        except ProcessLookupError:
            return False
        self.chars = chars
        self.sent += 1
        return True
