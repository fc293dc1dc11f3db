"""Typed errors of the knowledge-graph layer.

Every error a user can meet derives from :class:`PlantKGError`, carries the exit code the CLI uses,
and says what to change (``hint``). The CLI prints ``str(error)`` and exits; it never shows a
traceback for these.

Exit codes follow ``plantkg validate``: 0 valid, 1 violations (not an exception: a report),
2 unusable input (these errors).
"""

from __future__ import annotations

from pathlib import Path

EXIT_VIOLATIONS = 1
EXIT_UNUSABLE = 2


class PlantKGError(Exception):
    """Base of every user-facing error. ``hint`` says what to do next."""

    exit_code = EXIT_UNUSABLE

    def __init__(self, message: str, *, hint: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.hint = hint

    def __str__(self) -> str:
        return f"{self.message}\n  hint: {self.hint}" if self.hint else self.message


class InputError(PlantKGError):
    """A plant file cannot be used: missing, not a file, not text, unknown format, empty."""

    def __init__(self, path: Path | str, problem: str, *, hint: str | None = None) -> None:
        super().__init__(f"{path}: {problem}", hint=hint)
        self.path = str(path)
        self.problem = problem


class RdfSyntaxError(InputError):
    """A plant file does not parse; names file, line, column and shows the offending text."""

    def __init__(
        self, path: Path | str, line: int | None, column: int | None, problem: str, excerpt: str
    ) -> None:
        where = f"{path}:{line}:{column}" if line is not None else str(path)
        caret = ""
        if excerpt and column is not None:
            caret = "\n    " + " " * max(column - 1, 0) + "^"
        text = f"{where}: syntax error: {problem}"
        if excerpt:
            text += f"\n    {excerpt}{caret}"
        PlantKGError.__init__(self, text, hint="fix the RDF syntax at that position")
        self.path = str(path)
        self.problem = problem
        self.line = line
        self.column = column
        self.excerpt = excerpt


class NotAPlantError(PlantKGError):
    """The files parse but describe no plant (no triple uses a plantkg term)."""


class ShapesError(PlantKGError):
    """The shapes graph itself is unusable (for example, a feature the fast engine cannot run)."""


class QueryError(PlantKGError):
    """A SPARQL query is malformed or cannot be run."""
