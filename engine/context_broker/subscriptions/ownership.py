"""Whose subscription it is, and what a principal may subscribe to (docs/security.md).

On a closed context broker (engine.context_broker.access) a request comes from plantkg's own
token (the agent's) or from a principal. The gate lets a principal through to
``/v2/subscriptions``; the rules that need the parsed subscription are here, checked by the
registry on ``POST`` and on the merged result of a ``PATCH``:

- a principal may hold a subscription only when each ``subject.entities[]`` names an ``id`` it
  may read (or write): an ``idPattern`` (with or without a ``typePattern``) would watch entities
  it may not read; else 403 naming the principal and the entity;
- its notifications go to ``http``/``httpCustom`` URLs only: ``mqtt://`` and ``kafka://``
  notifications are plantkg's (a ``kafka://`` one logs in to the plant's closed Kafka as plantkg
  and trusts the plant CA), 403 with what to do instead;
- a subscription is its creator's: a principal sees, changes and deletes only its own (another's
  is 404, Orion's "not found", as if it did not exist: it learns nothing of it) and lists only its
  own; plantkg's token sees every one. Orion has no owner (telefonicaid/fiware-orion#3522 leaves it
  to the PEP proxy in front); this broker is its own PEP, so the owner is stored with the
  subscription (``owner`` in ``subscriptions.json``, never shown in its JSON);
- a principal's rights are those of the broker's principals file as it runs: when the plant takes
  a right away (or the principal), the broker restarts with the new file and a subscription its
  owner may no longer hold stops notifying (:func:`lapsed`, checked at each match; logged once).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

from engine.context_broker.contract import NgsiError
from engine.context_broker.subscriptions.model import HttpTarget, KafkaTarget, Subscription

#: Where the app leaves the request's :class:`Requester` for the subscriptions blueprint.
ENVIRON_KEY = "plantkg.subscriptions.requester"


@dataclass(frozen=True)
class Requester:
    """Who asks: ``name`` None is plantkg's own token (or a broker without principals): every
    subscription, any target. Else a principal, with the entity ids it may read or write."""

    name: str | None = None
    readable: frozenset[str] = frozenset()

    @property
    def plantkg(self) -> bool:
        return self.name is None


PLANTKG = Requester()


def may_see(who: Requester, sub: Subscription) -> bool:
    """Whether ``who`` may see (get, change, delete, list) ``sub``: its own, or plantkg's token."""
    return who.plantkg or sub.owner == who.name


def check_may_hold(who: Requester, sub: Subscription) -> None:
    """Nothing if ``who`` may hold ``sub`` (the rules in the module docstring), else 403."""
    if who.plantkg:
        return
    for sel in sub.entities:
        if sel.id is None:
            raise _forbidden(f"principal {who.name!r} may subscribe only to entities it names by id "
                             f"(subject.entities[].id), not to a pattern ({sel.id_pattern!r})")
        if sel.id not in who.readable:
            raise _forbidden(f"principal {who.name!r} may not read entity {sel.id!r}, so it may not "
                             "subscribe to it")
    target = sub.notification.target
    if not isinstance(target, HttpTarget):
        kind = "kafka" if isinstance(target, KafkaTarget) else "mqtt"
        raise _forbidden(f"principal {who.name!r} may not send notifications to {target.url!r} "
                         f"(notification.{kind}): {kind}:// notifications are plantkg's own (they reach the "
                         "plant's brokers as plantkg); give an http:// or https:// URL "
                         "(notification.http), or have the plant bridge the entity to the broker")


def lapsed(sub: Subscription, owners: Mapping[str, Requester]) -> str | None:
    """Why ``sub`` may no longer notify (its owner is no principal of ``owners``, the broker's
    principals as it runs, or may no longer hold it), or None (plantkg's, or still allowed)."""
    if sub.owner is None:
        return None
    who = owners.get(sub.owner)
    if who is None:
        return f"its owner {sub.owner!r} is no principal of this context broker any more"
    try:
        check_may_hold(who, sub)
    except NgsiError as err:
        return err.description
    return None


def _forbidden(description: str) -> NgsiError:
    return NgsiError(403, "Forbidden", description)
