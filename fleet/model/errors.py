"""Typed errors of the AGV model: a description that cannot become triples, a plant with no fleet.

Both derive from :class:`kg.errors.PlantKGError` (message + hint, exit code 2 in the CLI), so a
caller logs ``str(error)`` and has the field, the value and what to change in one line.
"""

from __future__ import annotations

from kg.errors import PlantKGError

#: How much of a refused value an error message shows (a 10 MB string is not repeated in a log).
SHOWN_VALUE_CHARS = 60


def shown(value: object) -> str:
    """``repr(value)``, cut to :data:`SHOWN_VALUE_CHARS` characters with the full length said."""
    text = repr(value)
    if len(text) <= SHOWN_VALUE_CHARS:
        return text
    return f"{text[:SHOWN_VALUE_CHARS]}... ({len(text)} characters)"


class FleetModelError(PlantKGError):
    """Base of the AGV model's errors."""


class DescriptionError(FleetModelError):
    """A factsheet or description refused before any triple is made.

    ``field`` is the path of the refused part (``physicalParameters.speedMax``,
    ``protocolFeatures.agvActions[3].actionType``, ``serialNumber``), ``value`` what was there
    (``None`` when missing), ``problem`` what is wrong with it.
    """

    def __init__(self, field: str, value: object, problem: str, *, hint: str | None = None) -> None:
        super().__init__(f"{field} = {shown(value)}: {problem}",
                         hint=hint or "fix the vehicle's factsheet or description; nothing was added "
                                      "to the graph")
        self.field = field
        self.value = value
        self.problem = problem


class BindingError(FleetModelError):
    """The plant does not say where the fleet lives (no fleet manager on an MQTT broker, or
    several candidates where one is needed)."""

    def __init__(self, problem: str, *, hint: str | None = None) -> None:
        super().__init__(problem, hint=hint or (
            "add a pk:Resource with pk:isType fleet:fleet-manager that pk:sendsTo the plant's "
            "Mosquitto broker (see ontology/examples/agv-fleet.ttl)"))
        self.problem = problem
