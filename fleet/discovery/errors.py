"""Typed errors of plug and play; each says what was wrong and what to do."""

from __future__ import annotations

from kg.errors import PlantKGError


class DiscoveryError(PlantKGError):
    """Base of plug and play's errors."""


class RefusedMessage(DiscoveryError):
    """A received message that cannot be used: its topic, size, JSON, schema or header."""

    def __init__(self, topic: str, reason: str) -> None:
        super().__init__(f"message on {topic[:200]!r} refused: {reason}",
                         hint="the vehicle must send messages that follow VDA 5050 2.1 "
                              "(or the paper's channel formats); nothing was changed")
        self.topic = topic
        self.reason = reason


class UnknownVehicleError(DiscoveryError):
    """A command names a vehicle the data directory does not hold."""

    def __init__(self, name: str, known: list[str]) -> None:
        listed = ", ".join(known[:10]) or "none"
        super().__init__(f"no discovered vehicle {name!r}",
                         hint=f"name it as SERIAL or MANUFACTURER/SERIAL; known: {listed}")
        self.name = name


class DataDirError(DiscoveryError):
    """The data directory cannot be used (missing, not a folder, a record that does not parse)."""
