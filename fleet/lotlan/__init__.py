"""LoTLan transport orders: parse and check a Logistic Task Language file into a Program.

LoTLan is the language the second paper's fleet manager takes its jobs in (Locations, Events,
TransportOrderSteps, Tasks with ``Transport From ... To ...``, ``TriggeredBy``, ``FinishedBy``,
``OnDone``, ``Repeat``). The grammar is written for lark (``lotlan.lark``) after the authors'
ANTLR grammar; the authors' implementation (PyPI lotlan-scheduler) is not used at run time (it
pins an old ANTLR runtime and SQLAlchemy 1.x and writes files into the working directory) but
serves as a differential test. Pure: no I/O beyond reading the file asked for.

    program = fleet.lotlan.load("jobs.tl")          # raises LotlanError with every problem
    diagnostics = fleet.lotlan.check_text(text, "jobs.tl")

docs/fleet-manager.md ("LoTLan") describes the language, the errors and the differences.
"""

from __future__ import annotations

from pathlib import Path

from fleet.lotlan import check as _check
from fleet.lotlan import syntax as _syntax
from fleet.lotlan.errors import Diagnostic, LotlanError
from fleet.lotlan.model import Program


def analyse(text: str, file: str = "<string>") -> tuple[Program | None, tuple[Diagnostic, ...]]:
    """The checked program (None when anything is wrong) and every problem, sorted by position."""
    return _check.check(_syntax.parse_text(text, file), file)


def check_text(text: str, file: str = "<string>") -> tuple[Diagnostic, ...]:
    """Every problem of a LoTLan text (empty when it is a usable program)."""
    return analyse(text, file)[1]


def parse(text: str, file: str = "<string>") -> Program:
    """The checked program; raises :class:`LotlanError` listing every problem."""
    program, diagnostics = analyse(text, file)
    if program is None:
        raise LotlanError(diagnostics)
    return program


def load(path: str | Path) -> Program:
    """Read and check a LoTLan file (UTF-8); raises :class:`LotlanError` listing every problem."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise LotlanError((Diagnostic(str(path), 1, 1, f"cannot read the file: {error}"),)) from error
    return parse(text, str(path))


__all__ = ["Diagnostic", "LotlanError", "Program", "analyse", "check_text", "load", "parse"]
