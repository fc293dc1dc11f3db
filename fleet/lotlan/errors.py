"""LoTLan diagnostics: one per problem, each with file, line, column and what to change.

A program is checked whole: :class:`LotlanError` carries every diagnostic of a file, not only
the first, and renders them as ``file:line:col: message`` lines (the format compilers use, so
editors can jump to them).
"""

from __future__ import annotations

from dataclasses import dataclass

from kg.errors import EXIT_VIOLATIONS, PlantKGError


@dataclass(frozen=True)
class Diagnostic:
    """One problem in a LoTLan file. ``line`` and ``column`` are 1-based."""

    file: str
    line: int
    column: int
    message: str

    def __str__(self) -> str:
        return f"{self.file}:{self.line}:{self.column}: {self.message}"

    def as_dict(self) -> dict[str, object]:
        return {"line": self.line, "column": self.column, "message": self.message}


class LotlanError(PlantKGError):
    """A LoTLan program that cannot be used; ``diagnostics`` lists every problem found."""

    exit_code = EXIT_VIOLATIONS

    def __init__(self, diagnostics: tuple[Diagnostic, ...]) -> None:
        files = sorted({d.file for d in diagnostics})
        super().__init__(
            "\n".join(str(d) for d in diagnostics),
            hint=f"fix the {len(diagnostics)} problem(s) above in {', '.join(files)}; "
            "nothing of the program was used",
        )
        self.diagnostics = diagnostics
