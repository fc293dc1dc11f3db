"""The planner's typed errors: each says what is wrong and what to do."""

from __future__ import annotations

from kg.errors import PlantKGError


class PlannerError(PlantKGError):
    """Base of the planner's errors."""


class TransitionError(PlannerError):
    """A transition the state tables (fleet/planner/states.py) do not allow."""


class BuildError(PlannerError):
    """A LoTLan task the planner cannot turn into a task (unknown station, unsupported trigger)."""


class JournalError(PlannerError):
    """The planner's journal cannot be read or written."""
