"""What the simulated vehicle can do: its action types, where each may be used, how long each takes.

Durations: ``pick``/``drop`` take their ``duration`` parameter (seconds) or the vehicle's default;
``wait``/``waitForTrigger`` take ``duration`` (default 1 s; the simulator has no trigger source, so
the duration stands in for it); ``startCharging``/``stopCharging`` are immediate but
``startCharging`` fails unless the vehicle stands on a charger. Instant-only actions
(``cancelOrder``, ``factsheetRequest``, ``stateRequest``) are handled by the vehicle itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from fleet.vda5050.factsheet import AgvAction
from fleet.vda5050.messages import Action

NODE_ACTIONS = ("pick", "drop", "wait", "waitForTrigger", "startCharging", "stopCharging")
INSTANT_ONLY = ("cancelOrder", "factsheetRequest", "stateRequest")
CHARGING = ("startCharging", "stopCharging")
TIMED = ("pick", "drop", "wait", "waitForTrigger")


@dataclass(frozen=True)
class ActionTimes:
    pick: float = 2.0
    drop: float = 2.0
    wait: float = 1.0


class ActionParameterError(ValueError):
    """A parameter of an action the vehicle knows has a value it cannot use."""


def duration(action: Action, times: ActionTimes) -> float:
    """Seconds ``action`` runs (0 for immediate ones); a bad ``duration`` raises, naming it."""
    if action.action_type not in TIMED:
        return 0.0
    default = {"pick": times.pick, "drop": times.drop}.get(action.action_type, times.wait)
    value = action.param("duration", default)
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            raise ActionParameterError(f"action {action.action_id} ({action.action_type}): duration {value!r} is not a number") from None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise ActionParameterError(f"action {action.action_id} ({action.action_type}): duration must be a number >= 0 s, got {value!r}")
    return float(value)


def catalogue() -> tuple[AgvAction, ...]:
    """The factsheet's ``protocolFeatures.agvActions`` of the simulated vehicle."""
    out = [AgvAction(t, ("NODE", "INSTANT") if t in CHARGING else ("NODE",),
                     description=f"simulated {t}", parameters=("duration",) if t in TIMED else ())
           for t in NODE_ACTIONS]
    out += [AgvAction(t, ("INSTANT",), description=f"{t} (section 6.8)") for t in INSTANT_ONLY]
    return tuple(out)
