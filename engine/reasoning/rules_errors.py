"""Typed errors of reasoning (``engine.reasoning.reason`` and its ``rules_*`` helpers).

Kept apart from :mod:`engine.reasoning.reason` so the helper modules can raise them without importing the
module that imports them. Each says what to change: the construct, the individual, the file.
"""

from __future__ import annotations

from engine.errors import EngineError


class ReasoningError(EngineError):
    """Base of every error :func:`engine.reasoning.reason.reason` raises on purpose."""


class UnsupportedConstructError(ReasoningError):
    """The fast engine cannot translate an OWL/SWRL construct; it refuses rather than ignore it.

    ``engine="auto"`` catches this and runs the owlready2 (HermiT) engine instead.
    """

    def __init__(self, construct: str, where: str, *, hint: str | None = None) -> None:
        super().__init__(
            f"the fast reasoner cannot translate {construct} (in {where})",
            hint=hint or "use --engine owlready2 (HermiT), or express it with the constructs "
            "docs/reasoning.md lists",
        )
        self.construct = construct
        self.where = where


class InconsistentPlantError(ReasoningError):
    """The plant contradicts the ontology: no world satisfies both."""

    def __init__(self, detail: str, *, individuals: tuple[str, ...] = (), classes: tuple[str, ...] = (),
                 engine: str = "") -> None:
        names = ", ".join((*individuals, *classes))
        text = f"the plant is inconsistent with the ontology: {detail}"
        if names and names not in detail:
            text += f" ({names})"
        super().__init__(
            text,
            hint="correct the named individuals (their types and property values) so they agree "
            "with the ontology's axioms; `plantkg validate` names most such mistakes",
        )
        self.detail = detail
        self.individuals = individuals
        self.classes = classes
        self.engine = engine


class ReasonerTimeoutError(ReasoningError):
    """The reference reasoner (HermiT in a JVM) did not finish before its deadline."""

    def __init__(self, timeout: float, resources: int | None = None) -> None:
        size = f" on {resources} individuals" if resources is not None else ""
        super().__init__(
            f"HermiT did not finish within {timeout:.0f} s{size} (its cost grows with the square of "
            "the plant)",
            hint="use the fast engine (--engine fast or auto), or give the reasoner more time",
        )
        self.timeout = timeout


class ReasonerFailedError(ReasoningError):
    """The reference reasoner could not run (Java error, unreadable output, worker crash)."""
