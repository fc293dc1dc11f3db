"""What one delivery attempt came to, as every sender reports it.

``retry`` says whether the same notification is tried again (after a backoff): true for the
temporary failures (no connection, timeout, HTTP 5xx, 408, 429, a broker not acknowledging),
false for a success and for permanent refusals (any other HTTP 4xx or 3xx), which are counted as
failures and then let go so the subscription's later notifications are not held up forever.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Result:
    ok: bool
    code: int | None = None
    reason: str = ""
    retry: bool = False

    @classmethod
    def success(cls, code: int | None = None) -> "Result":
        return cls(True, code)

    @classmethod
    def temporary(cls, reason: str, code: int | None = None) -> "Result":
        return cls(False, code, reason, retry=True)

    @classmethod
    def permanent(cls, reason: str, code: int | None = None) -> "Result":
        return cls(False, code, reason, retry=False)
