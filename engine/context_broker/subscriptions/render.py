"""The notification a triggered subscription sends: Orion's payload, rendered once, sent as is.

``{"subscriptionId": id, "data": [entity]}`` (always exactly one entity), the entity in the
subscription's ``attrsFormat``: ``normalized`` (``{"type", "value", "metadata"}`` per attribute),
``keyValues`` (values only), ``values`` (an array of values, in ``notification.attrs`` order),
``simplifiedNormalized`` / ``simplifiedKeyValues`` (the entity alone, no wrapper). Which
attributes: ``attrs`` (in that order; missing ones left out unless ``covered``, then ``null`` of
type ``None``) or all but ``exceptAttrs``; with ``onlyChangedAttrs`` only those the triggering
write changed. ``metadata`` keeps only the named metadata of each attribute.
"""

from __future__ import annotations

import json
import random
import uuid
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from engine.context_broker.contract import EntityChange
from engine.context_broker.subscriptions.model import AttrsFormat, Notification, Subscription

RESERVED = ("id", "type")


@dataclass(frozen=True)
class Outgoing:
    """One notification ready to send: the JSON body and what the transports put around it."""

    subscription_id: str
    body: bytes
    attrs_format: str
    service: str
    service_path: str
    entity_id: str
    correlator: str
    outbox_id: int = 0  # its record in the outbox (0: not logged); see .outbox


def selected_attrs(entity: Mapping[str, Any], n: Notification, changed: frozenset[str]) -> list[str]:
    """The attribute names to notify, in order."""
    present = [k for k in entity if k not in RESERVED]
    if n.attrs:
        names = [a for a in n.attrs if a in entity or n.covered]
    else:
        names = [a for a in present if a not in n.except_attrs]
    if n.only_changed_attrs:
        names = [a for a in names if a in changed]
    return names


def _attribute(entity: Mapping[str, Any], name: str, metadata: tuple[str, ...]) -> dict[str, Any]:
    attr = entity.get(name)
    if not isinstance(attr, Mapping):
        return {"type": "None", "value": None, "metadata": {}}
    md = attr.get("metadata") or {}
    if metadata:
        md = {k: v for k, v in md.items() if k in metadata}
    return {"type": attr.get("type", "None"), "value": attr.get("value"), "metadata": dict(md)}


def render_entity(entity: Mapping[str, Any], n: Notification, changed: frozenset[str]) -> Any:
    """The entity as it appears in ``data`` (or alone, for the simplified formats)."""
    names = selected_attrs(entity, n, changed)
    attrs = {name: _attribute(entity, name, n.metadata) for name in names}
    fmt = n.attrs_format
    if fmt is AttrsFormat.VALUES:
        return [a["value"] for a in attrs.values()]
    head = {"id": entity["id"], "type": entity["type"]}
    if fmt in (AttrsFormat.KEY_VALUES, AttrsFormat.SIMPLIFIED_KEY_VALUES):
        return head | {name: a["value"] for name, a in attrs.items()}
    return head | attrs


def payload(sub: Subscription, change: EntityChange) -> Any:
    entity = render_entity(change.entity, sub.notification, change.changed)
    if sub.notification.attrs_format in (AttrsFormat.SIMPLIFIED_NORMALIZED,
                                         AttrsFormat.SIMPLIFIED_KEY_VALUES):
        return entity
    return {"subscriptionId": sub.id, "data": [entity]}


def correlator() -> str:
    """A ``Fiware-Correlator`` in UUID 4 form. Not a secret, so from ``random`` (``uuid4`` reads
    os.urandom, which took ~80 us a call on the test machine, on the writing request's thread)."""
    return str(uuid.UUID(int=random.getrandbits(128), version=4))


def outgoing(sub: Subscription, change: EntityChange) -> Outgoing:
    body = json.dumps(payload(sub, change), separators=(",", ":"), ensure_ascii=False)
    return Outgoing(
        subscription_id=sub.id, body=body.encode("utf-8"),
        attrs_format=sub.notification.attrs_format.value,
        service=change.tenant.service, service_path=change.tenant.service_path,
        entity_id=change.entity_id, correlator=correlator(),
    )
