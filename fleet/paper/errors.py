"""Typed errors of the paper's channels; each names the field path and the value, and what to do."""

from __future__ import annotations

from typing import Any

from kg.errors import PlantKGError


class PaperError(PlantKGError):
    """Base of the paper-channel layer's errors."""


class ChannelError(PaperError):
    """An AGV id or a topic that cannot be used for the paper's channels."""

    def __init__(self, field: str, value: str, problem: str) -> None:
        super().__init__(f"{field} {value!r}: {problem}",
                         hint="agv ids use only A-Z a-z 0-9 _ . : - (at most 64 characters); topics are <agv-id>/<channel>")
        self.field = field
        self.value = value
        self.problem = problem


MISSING: Any = type("Missing", (), {"__repr__": lambda self: "(missing)"})()


class MessageError(PaperError):
    """A received (or built) message that breaks its schema or a rule the schema cannot express.

    ``value`` is what was found at ``path`` (:data:`MISSING` for a required field that is absent)."""

    def __init__(self, kind: str, path: str, value: Any, reason: str) -> None:
        self.kind = kind
        self.path = path
        self.value = value
        self.reason = reason
        super().__init__(f"{kind} refused: {self.short}",
                         hint=f"send a {kind} that satisfies fleet/paper/schemas/{kind}.json")

    @property
    def short(self) -> str:
        """``path = value: reason`` (no kind), for a status entry."""
        if not self.path:
            return self.reason
        if self.value is MISSING:
            return f"{self.path}: {self.reason}"
        return f"{self.path} = {_short(self.value)}: {self.reason}"


def _short(value: Any, limit: int = 80) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."
