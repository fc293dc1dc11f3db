"""The HMI's typed errors: each says what is wrong and what to do."""

from __future__ import annotations

from kg.errors import PlantKGError


class HmiError(PlantKGError):
    """The HMI cannot start (token file, map, LoTLan file, address)."""


class UpstreamDown(PlantKGError):
    """The planner or the fleet manager does not answer (the page says so; nothing is retried)."""

    def __init__(self, who: str, message: str) -> None:
        super().__init__(message)
        self.who = who


class UpstreamRefused(PlantKGError):
    """The planner answered a request with an error status (passed on to the operator)."""

    def __init__(self, who: str, status: int, description: str) -> None:
        super().__init__(f"the {who} refused: {status} {description}")
        self.who, self.status, self.description = who, status, description
