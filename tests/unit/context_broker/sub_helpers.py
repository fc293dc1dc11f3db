"""Shared helpers of the subscription unit tests: a small stand-in for the q language (the real
one is engine.context_broker.q, tested on its own), subscription documents, entity changes."""

from __future__ import annotations

from typing import Any

from engine.context_broker.contract import EntityChange, NgsiError, Tenant


class EqualsQuery:
    """``attr==value`` only: enough to see that the subscription engine consults q."""

    def __init__(self, text: str) -> None:
        if "==" not in text:
            raise NgsiError(400, "BadRequest", f"invalid query expression: {text!r}")
        self.attr, self.value = text.split("==", 1)

    def matches(self, entity: Any) -> bool:
        attr = entity.get(self.attr)
        return isinstance(attr, dict) and str(attr.get("value")) == self.value


def doc(**overrides: Any) -> dict[str, Any]:
    base: dict[str, Any] = {
        "subject": {"entities": [{"id": "Room1", "type": "Room"}]},
        "notification": {"http": {"url": "http://127.0.0.1:1028/accumulate"}},
    }
    base.update(overrides)
    return base


def entity(**attrs: Any) -> dict[str, Any]:
    out: dict[str, Any] = {"id": "Room1", "type": "Room"}
    for name, value in attrs.items():
        out[name] = {"type": "Number" if isinstance(value, (int, float)) else "Text",
                     "value": value, "metadata": {}}
    return out


def change(ent: dict[str, Any] | None = None, changed: set[str] | None = None,
           tenant: Tenant = Tenant(), **flags: bool) -> EntityChange:
    ent = ent if ent is not None else entity(temperature=23, humidity=70)
    names = changed if changed is not None else {k for k in ent if k not in ("id", "type")}
    return EntityChange(tenant=tenant, entity=ent, changed=frozenset(names), **flags)
