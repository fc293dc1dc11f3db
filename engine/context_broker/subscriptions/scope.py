"""Which service paths a subscription watches: Orion's rule for subscriptions.

orion-api.md ("Service path"): "All the queries without using Fiware-ServicePath (including
subscriptions) are on ``/#`` implicitly", and a subscription's service path "is the expression of
the query associated to the subscription", not where it belongs. So a subscription created with
no ``Fiware-ServicePath`` fires for entities of every path of its service; ``/a/#`` for ``/a``
and below; ``/a`` for exactly ``/a``; a comma-separated list for any of them. The text is kept
canonical (``/#``, ``/a/#``, ``/a,/b/#``) as the subscription's :class:`Tenant` ``service_path``,
so ``GET /v2/subscriptions`` with a ``Fiware-ServicePath`` lists those created with exactly it.
"""

from __future__ import annotations

from collections.abc import Mapping

from engine.context_broker.contract import Tenant
from engine.context_broker.params import read_scope
from engine.context_broker.store import ReadScope


def canonical(scope: ReadScope) -> str:
    return ",".join(("/#" if path == "/" else f"{path}/#") if recursive else path
                    for path, recursive in scope.paths)


def subscription_tenant(headers: Mapping[str, str]) -> Tenant:
    """The service and canonical service-path query of a request (400 for bad headers)."""
    scope = read_scope(headers)
    return Tenant(scope.service, canonical(scope))


def scope_of(tenant: Tenant) -> ReadScope:
    """The paths a subscription of ``tenant`` covers (``tenant.service_path`` as a query)."""
    return read_scope({"Fiware-Service": tenant.service, "Fiware-ServicePath": tenant.service_path})
