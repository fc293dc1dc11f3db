"""Typed errors of the VDA 5050 layer; each says what was wrong and what to change."""

from __future__ import annotations

from kg.errors import PlantKGError


class Vda5050Error(PlantKGError):
    """Base of the VDA 5050 layer's errors."""


class TopicError(Vda5050Error):
    """A topic level (manufacturer, serial number, ...) or a whole topic cannot be used."""

    def __init__(self, field: str, value: str, problem: str) -> None:
        super().__init__(
            f"{field} {value!r}: {problem}",
            hint="VDA 5050 topic levels must not contain '/', '+', '#' or '$'; serial numbers use "
            "only A-Z a-z 0-9 _ . : -",
        )
        self.field = field
        self.value = value
        self.problem = problem


class SchemaError(Vda5050Error):
    """A message refused by the official VDA 5050 JSON schema (or not JSON at all)."""

    def __init__(self, kind: str, path: str, reason: str) -> None:
        where = path or "(message)"
        super().__init__(
            f"{kind} message refused at {where}: {reason}",
            hint=f"send a {kind} message that satisfies the VDA 5050 2.1 JSON schema",
        )
        self.kind = kind
        self.path = path
        self.reason = reason


class MessageError(Vda5050Error):
    """A schema-valid message our types cannot represent (a field the simulator needs)."""

    def __init__(self, kind: str, field: str, problem: str) -> None:
        super().__init__(f"{kind}.{field}: {problem}")
        self.kind = kind
        self.field = field
        self.problem = problem
