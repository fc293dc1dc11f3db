"""Which subscriptions an entity change triggers: pure functions over a subscription and a change.

Orion's rules ("Notification Triggering", "Subscriptions based in alteration type"):

- tenant: the subscription's ``Fiware-Service`` is the entity's, and its service-path query
  covers the entity's path (none given at creation: every path, see :mod:`.scope`);
- subject: one of ``subject.entities`` selects the entity (``id`` exact or ``idPattern`` a regex
  found anywhere in the id, as Orion's ``regexec``; ``type``/``typePattern`` likewise, omitted =
  any type);
- alteration: a create fires ``entityCreate``, a delete ``entityDelete``, an update
  ``entityUpdate`` and ``entityChange`` (plantkg's writes report every written attribute as
  changed, so the two are the same here); the default is create + change, so deletes notify only
  when asked for;
- condition attrs: one of them is among the changed attributes (empty: any; ignored for deletes);
- expression ``q`` and ``mq``: match the entity after the change;
- state: ``active`` or ``oneshot``, not past ``expires``, and not inside the ``throttling``
  period since the last notification it triggered.
"""

from __future__ import annotations

import re
from functools import lru_cache
from collections.abc import Sequence
from typing import Any, Protocol

from engine.context_broker.contract import EntityChange
from engine.context_broker.subscriptions.model import Alteration, EntitySelector, Status, Subscription


class Query(Protocol):
    def matches(self, entity: Any) -> bool: ...


@lru_cache(maxsize=1024)
def _regex(pattern: str) -> re.Pattern[str]:
    return re.compile(pattern)


def selects(selector: EntitySelector, entity_id: str, entity_type: str) -> bool:
    if selector.id is not None and selector.id != entity_id:
        return False
    if selector.id_pattern is not None and not _regex(selector.id_pattern).search(entity_id):
        return False
    if selector.type is not None and selector.type != entity_type:
        return False
    if selector.type_pattern is not None and not _regex(selector.type_pattern).search(entity_type):
        return False
    return True


def alteration_fires(sub: Subscription, change: EntityChange) -> bool:
    wanted = sub.condition.alterations
    if change.deleted:
        return Alteration.DELETE in wanted
    if change.created:
        return Alteration.CREATE in wanted
    return bool(wanted & {Alteration.UPDATE, Alteration.CHANGE})


def attrs_fire(sub: Subscription, change: EntityChange) -> bool:
    if change.deleted:
        return True
    if not change.changed and not change.forced and not change.created:
        return False
    if not sub.condition.attrs:
        return True
    return bool(change.changed & set(sub.condition.attrs)) or (
        change.forced and not change.changed)


def is_live(sub: Subscription, now: float) -> bool:
    """Active or oneshot, and not expired."""
    if sub.status is Status.INACTIVE:
        return False
    return sub.expires is None or now < sub.expires


def throttled(sub: Subscription, last_triggered: float | None, now: float) -> bool:
    """Inside the throttling guard period (Orion discards such notifications)."""
    return bool(sub.throttling) and last_triggered is not None and now - last_triggered < sub.throttling


def triggers(sub: Subscription, change: EntityChange, queries: Sequence[Query] = ()) -> bool:
    """Tenant, subject, alteration, condition attrs and the parsed q/mq ``queries`` (state and
    throttling are separate)."""
    if not sub.scope.covers(change.tenant):
        return False
    if not any(selects(s, change.entity_id, change.entity_type) for s in sub.entities):
        return False
    if not alteration_fires(sub, change) or not attrs_fire(sub, change):
        return False
    return all(query.matches(change.entity) for query in queries)
