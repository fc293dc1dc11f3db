"""NGSI-v2's field syntax, shared by everything in plantkg that speaks it: the context broker
(engine/context_broker) checks requests against it, the MQTT -> NGSI bridge worker
(engine/bridge_worker) maps MQTT messages onto it. One copy, so the two can never disagree on
what Orion accepts (the bridge must not write what the broker would refuse).

Source: Orion's API manual, "Field syntax restrictions" and "Special attribute types".
"""

from __future__ import annotations

from typing import Any

#: Characters Orion refuses in names and in string values.
FORBIDDEN_CHARS = frozenset('<>"\'=;()')
#: Characters Orion refuses in ids, types and attribute names on top of :data:`FORBIDDEN_CHARS`.
NAME_ONLY_CHARS = frozenset("&?/#")
#: Longest id, type or attribute name.
MAX_NAME_LENGTH = 256


def default_attr_type(value: Any) -> str:
    """The attribute type Orion gives a value that comes without one."""
    if isinstance(value, bool):
        return "Boolean"
    if isinstance(value, (int, float)):
        return "Number"
    if isinstance(value, str):
        return "Text"
    if value is None:
        return "None"
    return "StructuredValue"
