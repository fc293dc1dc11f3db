"""``POST /v1/instantActions``: a request checked field by field, then one VDA 5050 instant action.

A request is ``{"serial", "manufacturer"?, "actionType", "actionParameters"?}``. ``actionType``
is one of the predefined actions of VDA 5050 2.1 (section 6.8) whose scope includes *instant*:
pick, drop, detectObject, finePositioning and waitForTrigger are node/edge actions only and are
refused here (send them in an order). ``actionParameters`` is a list of ``{"key": str, "value":
any JSON}``, or absent. The action is sent with blockingType NONE and an id the manager makes
(returned to the caller, who finds its status in the vehicle's ``actionStates``).

:func:`parse` is pure and raises :class:`InstantActionError` naming the field and the value.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from fleet.discovery.errors import DiscoveryError
from fleet.vda5050.messages import Action, ActionParameter, BlockingType

#: VDA 5050 2.1, section 6.8: the predefined actions with "instant" among their scopes.
INSTANT_ACTIONS: tuple[str, ...] = (
    "startPause", "stopPause", "startCharging", "stopCharging", "initPosition", "stateRequest", "logReport",
    "cancelOrder", "factsheetRequest",
)
MAX_PARAMETERS = 50


class InstantActionError(DiscoveryError):
    """A request for an instant action that cannot be sent: which field, what is wrong."""


@dataclass(frozen=True)
class InstantRequest:
    serial: str
    manufacturer: str | None
    action_type: str
    parameters: tuple[ActionParameter, ...] = ()

    def action(self, action_id: str) -> Action:
        return Action(self.action_type, action_id, BlockingType.NONE, self.parameters)


def _text(body: dict[str, Any], key: str, *, required: bool) -> str | None:
    value = body.get(key)
    if value is None and not required:
        return None
    if not isinstance(value, str) or not value:
        raise InstantActionError(f"{key}: expected a non-empty string, got {value!r}"[:300])
    return value


def parse(body: Any) -> InstantRequest:
    if not isinstance(body, dict):
        raise InstantActionError(f"the body is a JSON object {{serial, actionType, ...}}, got {type(body).__name__}")
    unknown = sorted(set(body) - {"serial", "manufacturer", "actionType", "actionParameters"})
    if unknown:
        raise InstantActionError(f"{unknown[0]}: not a field of an instant action request "
                                 "(serial, manufacturer, actionType, actionParameters)"[:300])
    serial = _text(body, "serial", required=True)
    manufacturer = _text(body, "manufacturer", required=False)
    action_type = _text(body, "actionType", required=True)
    if action_type not in INSTANT_ACTIONS:
        raise InstantActionError(f"actionType: {action_type!r} is not a predefined VDA 5050 2.1 instant action "
                                 f"(one of {', '.join(INSTANT_ACTIONS)})"[:500])
    raw = body.get("actionParameters", [])
    if not isinstance(raw, list):
        raise InstantActionError(f"actionParameters: expected a list of {{key, value}}, got {type(raw).__name__}")
    if len(raw) > MAX_PARAMETERS:
        raise InstantActionError(f"actionParameters: {len(raw)} parameters, at most {MAX_PARAMETERS}")
    params = []
    for i, p in enumerate(raw):
        if not isinstance(p, dict) or set(p) != {"key", "value"}:
            raise InstantActionError(f"actionParameters[{i}]: expected {{\"key\", \"value\"}}, got {p!r}"[:300])
        if not isinstance(p["key"], str) or not p["key"]:
            raise InstantActionError(f"actionParameters[{i}].key: expected a non-empty string, got {p['key']!r}"[:300])
        params.append(ActionParameter(p["key"], p["value"]))
    assert serial is not None and action_type is not None
    return InstantRequest(serial, manufacturer, action_type, tuple(params))
