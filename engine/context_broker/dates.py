"""Orion's DateTime values: parse ISO 8601 as Orion accepts it, render as Orion answers it.

Orion (orion-api.md, "Datetime support") accepts ``<date>``, ``<date>T<time>`` and
``<date>T<time><timezone>`` with ``YYYY-MM-DD``, times ``hh:mm:ss.sss``/``hhmmss.sss``,
``hh:mm:ss``/``hhmmss``, ``hh:mm``/``hhmm`` or ``hh``, and zones ``Z``, ``±hh:mm``, ``±hhmm``,
``±hh``; no zone means UTC. It renders ``YYYY-MM-DDThh:mm:ss.sssZ``. Used by the q language
(date comparisons) and by the entity layer (``DateTime`` attributes, ``dateCreated`` /
``dateModified``).
"""

from __future__ import annotations

import re
from datetime import datetime, timedelta, timezone

_DATETIME = re.compile(
    r"(?P<y>\d{4})-(?P<mo>\d{2})-(?P<d>\d{2})"
    r"(?:T(?P<h>\d{2})(?::?(?P<mi>\d{2})(?::?(?P<s>\d{2})(?:\.(?P<frac>\d{1,9}))?)?)?"
    r"(?P<tz>Z|[+-]\d{2}(?::?\d{2})?)?)?\Z")


def parse_datetime(text: str) -> datetime | None:
    """The aware UTC datetime ``text`` denotes, or None when it is not an Orion ISO 8601 date."""
    match = _DATETIME.match(text)
    if match is None:
        return None
    g = match.groupdict()
    frac = g["frac"] or "0"
    micro = int((frac + "000000")[:6])
    try:
        value = datetime(int(g["y"]), int(g["mo"]), int(g["d"]), int(g["h"] or 0), int(g["mi"] or 0),
                         int(g["s"] or 0), micro, tzinfo=timezone.utc)
    except ValueError:
        return None
    tz = g["tz"]
    if tz and tz != "Z":
        sign = 1 if tz[0] == "+" else -1
        digits = tz[1:].replace(":", "")
        offset = timedelta(hours=int(digits[:2]), minutes=int(digits[2:4] or 0))
        value -= sign * offset
    return value


def render_datetime(value: datetime) -> str:
    """``YYYY-MM-DDThh:mm:ss.sssZ`` in UTC, as Orion renders DateTime values."""
    value = value.astimezone(timezone.utc)
    return value.strftime("%Y-%m-%dT%H:%M:%S.") + f"{value.microsecond // 1000:03d}Z"


def from_epoch(seconds: float) -> str:
    return render_datetime(datetime.fromtimestamp(seconds, timezone.utc))
