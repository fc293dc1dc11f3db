"""Where a command's output goes and how it asks a person: this process's terminal, or (through
``plantkg serve``'s control socket, engine.control.server) the terminal of the command that asked.

``make_changes`` (apply, destroy) writes and asks only through a :class:`Console`, so the same
code prints the same plan, progress and summary whichever process runs it.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from contextlib import AbstractContextManager
from typing import TYPE_CHECKING, Protocol

import click

if TYPE_CHECKING:
    from engine.apply import ApplyEvent


class Console(Protocol):
    """Output, the one question (confirmation) and apply's progress display."""

    def echo(self, text: str = "", *, err: bool = False) -> None:
        """A line for stdout (``err``: stderr); click styles are kept only where colours show."""

    @property
    def interactive(self) -> bool:
        """Whether a person can be asked (the command's standard input is a terminal)."""

    def prompt(self, question: str) -> str:
        """Show ``question`` and return the line the person typed (raises click.Abort if none can)."""

    def progress(self) -> AbstractContextManager[Callable[[ApplyEvent], None]]:
        """The ``on_event`` of apply, as a context manager."""


class Terminal:
    """This process's own stdin, stdout and stderr."""

    def echo(self, text: str = "", *, err: bool = False) -> None:
        click.echo(text, err=err)

    @property
    def interactive(self) -> bool:
        return sys.stdin.isatty()

    def prompt(self, question: str) -> str:
        click.echo(question)
        answer: str = click.prompt("  Enter a value", default="", show_default=False)
        return answer

    def progress(self) -> AbstractContextManager[Callable[[ApplyEvent], None]]:
        from engine.cli.progress import Progress  # noqa: PLC0415 - imports apply

        return Progress()


TERMINAL = Terminal()
