"""plantkg's own principals: the clients plantkg itself runs against the plant's brokers.

A closed broker admits only users, so every client plantkg runs needs a user there too. Their
names start with ``plantkg.`` (a plant resource may not take such a ``pk:id``: engine.derived.access
refuses it), and their passwords are never configured: each is derived from the plant's principal
key (:mod:`engine.security.principal_key`) on the machine that needs it, so nothing secret travels
in a spec, a plan or a request.

| principal | who | may |
|---|---|---|
| ``plantkg.agent`` | the broker's agent: health check, bridge states | read ``$SYS/#`` |
| ``plantkg.observer`` | the dashboard's rates, ``check``'s taps, the demo's taps | read every topic (``#``) |
| ``plantkg.check`` | ``plantkg check``'s probes | write every topic (``#``) |
| ``plantkg.bridge.<local>.<remote>`` | a bridge, on the broker it connects to | exactly the topics it forwards there |
| ``plantkg.notify.<local>.<remote>`` | the context broker's notifications of an MQTT <-> NGSI bridge | write the topics the bridge brings back |
| ``plantkg.fleet`` (a type's ``pk:principalName``) | a resource plantkg runs: the fleet manager | what the rules let the resource write and read |

The first three are the same on every broker (its driver adds them); a bridge's principal is
derived from the bridge (engine.derived.access) and shows in the plan like a plant user; so is
the principal of a resource whose type names one (``pk:principalName``).
"""

from __future__ import annotations

PREFIX = "plantkg."
AGENT = "plantkg.agent"
OBSERVER = "plantkg.observer"
CHECK = "plantkg.check"
#: The principals every users file of a Mosquitto holds (its driver adds them).
FIXED = frozenset({AGENT, OBSERVER, CHECK})
#: The ``secret_ref`` of a principal whose password is derived from the principal key.
PRINCIPAL_REF = "plantkg:principal-key"


def bridge_principal(local_id: str, remote_id: str) -> str:
    """The user a bridge carried by ``local_id`` has on the broker it connects to."""
    return f"{PREFIX}bridge.{local_id}.{remote_id}"


def notify_principal(local_id: str, remote_id: str) -> str:
    """The user the context broker publishes an MQTT <-> NGSI bridge's notifications as, on the
    bridge's MQTT broker ``local_id``: a principal of its own, writing exactly the topics the
    bridge brings back (the worker's principal reads what it forwards)."""
    return f"{PREFIX}notify.{local_id}.{remote_id}"


def is_reserved(name: str) -> bool:
    """True for a name only plantkg's own principals may have."""
    return name.startswith(PREFIX)
