"""Orion's subscriptions and notifications for plantkg's context broker.

:class:`~.service.SubscriptionService` is the part the app wires in: its Flask blueprint serves
``/v2/subscriptions``, its ``entity_changed`` is the :class:`~engine.context_broker.contract.ChangeListener`
the entity layer calls after each durable write. Inside, one module per job: :mod:`.model`
(frozen dataclasses, rendering), :mod:`.parse` with :mod:`.fields` and :mod:`.parse_targets`
(validation), :mod:`.matcher` (which
subscriptions a change triggers), :mod:`.render` (the notification), :mod:`.registry` (durable
CRUD and delivery status), :mod:`.delivery` (per-subscription lanes, retries with backoff) and
the senders :mod:`.http`, :mod:`.mqtt`, :mod:`.kafka`; :mod:`.ownership` (what a principal of a
closed broker may subscribe to, and whose a subscription is). See docs/context-broker-subscriptions.md.
"""

from engine.context_broker.subscriptions.service import SubscriptionService

__all__ = ["SubscriptionService"]
