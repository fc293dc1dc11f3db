"""Shared helpers of the subscription unit tests: subscription documents, entity changes, and
the q language the subscriptions use (engine.context_broker.q, tested on its own)."""

from __future__ import annotations

from typing import Any

from engine.context_broker.contract import EntityChange, Tenant
from engine.context_broker.q import parse_q


def queries(sub: Any) -> tuple[Any, ...]:
    """The parsed q and mq of a subscription, as the service builds them."""
    out = []
    if sub.condition.q is not None:
        out.append(parse_q(sub.condition.q))
    if sub.condition.mq is not None:
        out.append(parse_q(sub.condition.mq, metadata=True))
    return tuple(out)


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
