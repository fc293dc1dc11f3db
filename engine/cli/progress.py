"""Progress of ``apply``/``destroy`` for people.

Each change prints a line when it starts and when it ends (with its time), like Terraform's
"Creating... / Creation complete after 3s". In a terminal a status line below them shows what is
running and for how long, redrawn in place (a background ticker refreshes it twice a second);
elsewhere (CI logs, pipes) only the plain lines are written.
"""

from __future__ import annotations

import shutil
import sys
import threading
import time
from collections.abc import Callable
from typing import IO

import click

from engine.apply import ApplyEvent, ApplyResult, EventKind, OutcomeStatus
from engine.model import Action

_VERBS = {
    Action.CREATE: ("Creating", "Created"),
    Action.UPDATE: ("Updating", "Updated"),
    Action.REPLACE: ("Replacing", "Replaced"),
    Action.DELETE: ("Destroying", "Destroyed"),
    Action.NOOP: ("Checking", "Checked"),
}


def duration(seconds: float) -> str:
    """``0.4s``, ``12s``, ``3m05s``, ``2h01m``, ``3d04h``."""
    if seconds < 10:
        return f"{seconds:.1f}s"
    s = int(seconds)
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    if s < 86400:
        return f"{s // 3600}h{s % 3600 // 60:02d}m"
    return f"{s // 86400}d{s % 86400 // 3600:02d}h"


def event_line(event: ApplyEvent) -> str | None:
    """The plain line for one event (None for events without one)."""
    doing, done = _VERBS[event.action]
    if event.kind is EventKind.START:
        return f"{event.address}: {doing}..."
    if event.kind is EventKind.DONE:
        tries = f" ({event.attempt} attempts)" if event.attempt > 1 else ""
        return click.style(f"{event.address}: {done} after {duration(event.elapsed)}{tries}", fg="green")
    if event.kind is EventKind.RETRY:
        return click.style(f"{event.address}: attempt {event.attempt} failed: {event.message}", fg="yellow")
    if event.kind is EventKind.FAILED:
        return click.style(f"{event.address}: FAILED after {duration(event.elapsed)}: {event.message}",
                           fg="red", bold=True)
    if event.kind is EventKind.SKIPPED:
        return click.style(f"{event.address}: skipped ({event.message})", fg="yellow")
    if event.kind is EventKind.VERIFY:
        return "Checking the result: asking the agents again..."
    return None


class Progress:
    """``on_event`` for apply; use as a context manager (starts/stops the live ticker)."""

    def __init__(self, stream: IO[str] | None = None, *, live: bool | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.stream = stream if stream is not None else sys.stdout
        self.live = self.stream.isatty() if live is None else live
        self.clock = clock
        self.running: dict[str, float] = {}
        self.finished = 0
        self.lock = threading.Lock()
        self._stop = threading.Event()
        self._ticker: threading.Thread | None = None
        self._status_shown = False

    def __enter__(self) -> Progress:
        if self.live:
            self._ticker = threading.Thread(target=self._tick, name="progress", daemon=True)
            self._ticker.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join()
        with self.lock:
            self._clear_status()

    def __call__(self, event: ApplyEvent) -> None:
        with self.lock:
            if event.kind is EventKind.START:
                self.running[event.address] = self.clock()
            elif event.kind in (EventKind.DONE, EventKind.FAILED, EventKind.SKIPPED):
                self.running.pop(event.address, None)
                self.finished += 1
            line = event_line(event)
            if line is None:
                return
            if self.live and event.kind is EventKind.START:
                self._draw_status()  # a start only shows in the status line
                return
            self._clear_status()
            click.echo(line, file=self.stream, color=self.live or None)
            self._draw_status()

    def _tick(self) -> None:
        while not self._stop.wait(0.5):
            with self.lock:
                self._draw_status()

    def _clear_status(self) -> None:
        if self.live and self._status_shown:
            self.stream.write("\r\x1b[2K")
            self.stream.flush()
            self._status_shown = False

    def _draw_status(self) -> None:
        if not self.live or not self.running:
            self._clear_status()
            return
        now = self.clock()
        items = sorted(self.running.items(), key=lambda kv: kv[1])
        shown = ", ".join(f"{a} {duration(now - t)}" for a, t in items[:3])
        more = f" +{len(items) - 3}" if len(items) > 3 else ""
        text = f"  … {self.finished} done, running: {shown}{more}"
        width = shutil.get_terminal_size((100, 24)).columns
        self.stream.write("\r\x1b[2K" + click.style(text[: max(20, width - 1)], dim=True))
        self.stream.flush()
        self._status_shown = True


def result_lines(result: ApplyResult, *, verb: str = "Apply") -> list[str]:
    """The closing summary of an apply (or destroy)."""
    n_ok, n_failed, n_skipped = len(result.changed), len(result.failed), len(result.skipped)
    counts = f"{n_ok} changed, {n_failed} failed, {n_skipped} skipped in {duration(result.seconds)}"
    lines: list[str] = []
    if result.ok:
        lines.append(click.style(f"{verb} complete: {counts}.", fg="green", bold=True))
        lines.append("No broker of the plant runs any more." if verb == "Destroy" else
                     "The agents report the plant as described: nothing left to do.")
        return lines
    lines.append(click.style(f"{verb} finished with problems: {counts}.", fg="red", bold=True))
    for outcome in result.outcomes:
        if outcome.status is OutcomeStatus.FAILED:
            lines.append(f"  ✗ {outcome.change.address}: {outcome.error}")
        elif outcome.status is OutcomeStatus.SKIPPED:
            lines.append(f"  - {outcome.change.address}: {outcome.error}")
    if result.unexpected:
        lines.append("Unexpected results (a driver did something else than it reported):")
        lines.extend(f"  ! {u.address}: {u.detail}" for u in result.unexpected)
    if result.after is not None and not result.after.empty:
        left = ", ".join(c.address for c in result.after.pending)
        lines.append(f"Still to do: {left}")
    lines.append(f"Fix the cause and run `plantkg {verb.lower()}` again; what is done is not repeated.")
    return lines
