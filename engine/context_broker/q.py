"""Orion's Simple Query Language (``q``, and ``mq`` for metadata), parsed once, matched many times.

orion-api.md, "Simple Query Language": statements joined by ``;`` (AND). A statement is unary
(``temperature`` exists, ``!temperature`` does not) or binary: an attribute path, an operator and
a value.

- Operators ``==`` (also ``:``), ``!=``, ``>``, ``<``, ``>=``, ``<=`` and ``~=`` (a regular
  expression searched in a string). ``==``/``!=`` take a list ``a==x,y`` (any of / none of) or a
  range ``a==1..5`` (both ends included); the others a single value.
- The path is ``attr`` or ``attr.key.key`` into a StructuredValue; a token holding ``.`` is
  written in single quotes (``'a.b'.c``). In ``mq`` the second token is a metadata name.
- Values: ``'quoted'`` is always a string; unquoted ``true``/``false`` is a boolean, ``null``
  null, a number compares numerically with numbers (and ``==``/``!=`` also match the same text
  as a string, as Orion: ``title=='20'`` matches only the string), an ISO 8601 date compares as a
  date with date strings (DateTime attributes); anything else is a string (ordered
  lexicographically). A list value matches ``==`` when it contains the query value.
- Every binary statement needs the target property: ``!=`` does not match an entity without it.

:func:`parse_q` raises :class:`NgsiError` 400 ``BadRequest`` naming the character position and
the problem; :meth:`Query.matches` takes an entity in normalized JSON. Pure: no I/O, no state.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from functools import partial
from datetime import datetime
from typing import Any

from engine.context_broker.contract import NgsiError, bad_request
from engine.context_broker.dates import parse_datetime

TWO_CHAR_OPS = ("==", "!=", ">=", "<=", "~=")
ONE_CHAR_OPS = (">", "<")
ORDER_OPS = (">", "<", ">=", "<=")
MAX_Q_LENGTH = 4096
_NUMBER = re.compile(r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?\Z")
_MISSING = object()


@dataclass(frozen=True)
class Literal:
    """One query value: ``kind`` is number, string, boolean, null or date; ``text`` as written."""

    kind: str
    value: Any
    text: str
    quoted: bool = False


@dataclass(frozen=True)
class Statement:
    """``op`` is ``exists``, ``absent`` or a binary operator (``:`` is stored as ``==``).
    ``values`` for a single value or a list; ``low``/``high`` for a range; ``position``: where
    the statement starts in the query text."""

    path: tuple[str, ...]
    op: str
    values: tuple[Literal, ...] = ()
    low: Literal | None = None
    high: Literal | None = None
    pattern: re.Pattern[str] | None = None
    position: int = 0

    @property
    def attribute(self) -> str:
        return self.path[0]


@dataclass(frozen=True)
class Query:
    """A parsed ``q`` (or ``mq`` when ``metadata``): all statements must match."""

    text: str
    statements: tuple[Statement, ...]
    metadata: bool = False

    @property
    def attributes(self) -> frozenset[str]:
        """The attribute names the query looks at."""
        return frozenset(s.attribute for s in self.statements)

    def matches(self, entity: Mapping[str, Any]) -> bool:
        for test in self.tests:
            if not test(entity):
                return False
        return True

    @property
    def tests(self) -> tuple[Callable[[Mapping[str, Any]], bool], ...]:
        """One predicate per statement: a specialized fast one for the common shapes (one
        attribute, a number or string), else the general matcher. Same answers (unit tested)."""
        cached = self.__dict__.get("_tests")
        if cached is None:
            cached = tuple(_compile(s, self.metadata) for s in self.statements)
            object.__setattr__(self, "_tests", cached)
        return cached


# --- parsing -----------------------------------------------------------------------------

def parse_q(text: str, *, metadata: bool = False) -> Query:
    """The query ``text`` denotes; :class:`NgsiError` 400 naming the position and the problem."""
    param = "mq" if metadata else "q"
    if not isinstance(text, str) or not text.strip():
        raise bad_request(f"empty {param}: give at least one statement such as temperature>20")
    if len(text) > MAX_Q_LENGTH:
        raise bad_request(f"{param} too long: {len(text)} characters, at most {MAX_Q_LENGTH}")
    statements = []
    for start, part in _split(text, ";", 0, param):
        if not part.strip():
            raise bad_request(f"{param}: empty statement at character {start} (two ';' in a row, "
                              "or a ';' at the start or end)")
        statements.append(_statement(part, start, param, metadata))
    return Query(text, tuple(statements), metadata)


def _split(text: str, sep: str, base: int, param: str) -> list[tuple[int, str]]:
    """``text`` cut at ``sep`` outside single quotes: (offset in the query, piece) pairs."""
    pieces, start, i, quoted = [], 0, 0, False
    while i < len(text):
        char = text[i]
        if char == "'":
            quoted = not quoted
        elif not quoted and text.startswith(sep, i):
            pieces.append((base + start, text[start:i]))
            i += len(sep)
            start = i
            continue
        i += 1
    if quoted:
        raise bad_request(f"{param}: unterminated quote (') in {text!r} starting at character "
                          f"{base + text.rfind(chr(39), 0)}")
    pieces.append((base + start, text[start:]))
    return pieces


def _find_operator(text: str) -> tuple[int, str] | None:
    quoted = False
    for i, char in enumerate(text):
        if char == "'":
            quoted = not quoted
            continue
        if quoted:
            continue
        pair = text[i:i + 2]
        if pair in TWO_CHAR_OPS:
            return i, pair
        if char in ONE_CHAR_OPS:
            return i, char
    quoted = False
    for i, char in enumerate(text):
        if char == "'":
            quoted = not quoted
        elif char == ":" and not quoted:
            return i, ":"
    return None


def _statement(part: str, start: int, param: str, metadata: bool) -> Statement:
    found = _find_operator(part)
    if found is None:
        negated = part.startswith("!")
        path_text = part[1:] if negated else part
        path = _path(path_text, start + int(negated), param, metadata)
        return Statement(path, "absent" if negated else "exists", position=start)
    at, op = found
    lhs, rhs = part[:at], part[at + len(op):]
    where = f"{param}: statement {part!r} at character {start}"
    if not lhs:
        raise bad_request(f"{where}: no attribute before the operator {op!r}")
    path = _path(lhs, start, param, metadata)
    if not rhs:
        raise bad_request(f"{where}: no value after {'.'.join(path)}{op}")
    op = "==" if op == ":" else op
    rhs_start = start + at + len(found[1])
    items = _split(rhs, ",", rhs_start, param)
    ranges = _split(rhs, "..", rhs_start, param)
    if op in ORDER_OPS + ("~=",):
        if len(items) > 1:
            raise bad_request(f"{where}: a list of values is allowed only with == and != "
                              f"(character {items[1][0] - 1})")
        if len(ranges) > 1:
            raise bad_request(f"{where}: a range (..) is allowed only with == and != "
                              f"(character {ranges[1][0] - 2})")
    if op == "~=":
        literal = _literal(rhs, rhs_start, where)
        try:
            pattern = re.compile(str(literal.value) if literal.kind == "string" else literal.text)
        except re.error as err:
            raise bad_request(f"{where}: bad regular expression {rhs!r}: {err}") from None
        return Statement(path, op, (literal,), pattern=pattern, position=start)
    if len(items) == 1 and len(ranges) == 2:
        low = _literal(ranges[0][1], ranges[0][0], where)
        high = _literal(ranges[1][1], ranges[1][0], where)
        if low.kind != high.kind or low.kind not in ("number", "string", "date"):
            raise bad_request(f"{where}: a range needs two numbers, two dates or two strings, got "
                              f"{low.text!r} ({low.kind}) and {high.text!r} ({high.kind})")
        return Statement(path, op, low=low, high=high, position=start)
    if len(ranges) > 2 or (len(ranges) > 1 and len(items) > 1):
        raise bad_request(f"{where}: a range is written low..high, once, and not inside a list")
    values = tuple(_literal(item, offset, where) for offset, item in items)
    return Statement(path, op, values, position=start)


def _path(text: str, start: int, param: str, metadata: bool) -> tuple[str, ...]:
    tokens = []
    for offset, token in _split(text, ".", start, param):
        if len(token) >= 2 and token[0] == "'" and token[-1] == "'":
            token = token[1:-1]
        if not token:
            raise bad_request(f"{param}: empty name in attribute path {text!r} at character {offset}")
        for i, char in enumerate(token):
            if char in "'!=<>~" or char.isspace() or ord(char) < 32:
                raise bad_request(f"{param}: character {char!r} not allowed in attribute path "
                                  f"{text!r} (character {offset + i})")
        tokens.append(token)
    if metadata and len(tokens) < 2:
        raise bad_request(f"mq: {text!r} at character {start} names no metadata: write "
                          "attribute.metadata (e.g. temperature.accuracy)")
    return tuple(tokens)


def _literal(text: str, offset: int, where: str) -> Literal:
    if not text:
        raise bad_request(f"{where}: empty value at character {offset}")
    if text[0] == "'":
        if len(text) < 2 or text[-1] != "'" or "'" in text[1:-1]:
            raise bad_request(f"{where}: a quoted value is one '...' with no quote inside "
                              f"(character {offset})")
        return Literal("string", text[1:-1], text, quoted=True)
    if "'" in text:
        raise bad_request(f"{where}: quote inside the unquoted value {text!r} at character "
                          f"{offset + text.index(chr(39))}")
    if text in ("true", "false"):
        return Literal("boolean", text == "true", text)
    if text == "null":
        return Literal("null", None, text)
    if _NUMBER.match(text):
        number = float(text)
        return Literal("number", int(number) if number.is_integer() and abs(number) < 2**53 else number, text)
    date = parse_datetime(text)
    if date is not None:
        return Literal("date", date, text)
    return Literal("string", text, text)


# --- matching ----------------------------------------------------------------------------

def _target(entity: Mapping[str, Any], path: tuple[str, ...], metadata: bool) -> Any:
    attr = entity.get(path[0])
    if not isinstance(attr, Mapping):
        return _MISSING
    rest = path[1:]
    if metadata:
        meta = attr.get("metadata")
        item = meta.get(path[1]) if isinstance(meta, Mapping) else None
        if not isinstance(item, Mapping):
            return _MISSING
        value, rest = item.get("value"), path[2:]
    else:
        if "value" not in attr:
            return _MISSING
        value = attr["value"]
    for key in rest:
        if not isinstance(value, Mapping) or key not in value:
            return _MISSING
        value = value[key]
    return value


def _comparable(literal: Literal, value: Any) -> Any:
    """``value`` in ``literal``'s domain (a number, datetime, string, bool), or _MISSING."""
    kind = literal.kind
    if kind == "number":
        return value if isinstance(value, (int, float)) and not isinstance(value, bool) else _MISSING
    if kind == "date":
        return (parse_datetime(value) or _MISSING) if isinstance(value, str) else _MISSING
    if kind == "string":
        return value if isinstance(value, str) else _MISSING
    if kind == "boolean":
        return value if isinstance(value, bool) else _MISSING
    return _MISSING


def _equal(literal: Literal, value: Any) -> bool:
    if isinstance(value, list):
        return any(_equal(literal, item) for item in value)
    if literal.kind == "null":
        return value is None
    if not literal.quoted and isinstance(value, str) and value == literal.text:
        return True
    other = _comparable(literal, value)
    return other is not _MISSING and other == literal.value


def _between(low: Literal, high: Literal, value: Any) -> bool:
    lo, hi = _comparable(low, value), _comparable(high, value)
    return lo is not _MISSING and low.value <= lo <= high.value


def _order(op: str, literal: Literal, value: Any) -> bool:
    other = _comparable(literal, value)
    if other is _MISSING or literal.kind in ("boolean", "null"):
        return False
    ref: Any = literal.value
    if isinstance(ref, datetime) != isinstance(other, datetime):
        return False
    if op == ">":
        return other > ref
    if op == "<":
        return other < ref
    if op == ">=":
        return other >= ref
    return other <= ref


_FAST_OPS: dict[str, Callable[[Any, Any], bool]] = {
    ">": lambda a, b: a > b, "<": lambda a, b: a < b, ">=": lambda a, b: a >= b, "<=": lambda a, b: a <= b,
}


def _compile(statement: Statement, metadata: bool) -> Callable[[Mapping[str, Any]], bool]:
    """A predicate for ``statement``; fast paths for a one-token path and a single number or
    string value, falling back to :func:`_matches` whenever the value is not a plain scalar."""
    general = partial(_matches, statement, metadata=metadata)
    if metadata or len(statement.path) != 1 or statement.low is not None:
        return general
    name, op = statement.path[0], statement.op
    if op in ("exists", "absent"):
        return general
    if len(statement.values) != 1 or op == "~=":
        return general
    literal = statement.values[0]
    ref = literal.value
    if literal.kind == "number" and op in _FAST_OPS:
        compare = _FAST_OPS[op]

        def number_order(entity: Mapping[str, Any]) -> bool:
            attr = entity.get(name)
            if type(attr) is not dict:
                return general(entity)
            value = attr.get("value")
            kind = type(value)
            if kind is int or kind is float:
                return compare(value, ref)
            return general(entity)
        return number_order
    if literal.kind in ("number", "string") and op in ("==", "!="):
        text, quoted, want = literal.text, literal.quoted, op == "=="
        numeric = literal.kind == "number"

        def equality(entity: Mapping[str, Any]) -> bool:
            attr = entity.get(name)
            if type(attr) is not dict or "value" not in attr:
                return general(entity)
            value = attr["value"]
            kind = type(value)
            if kind is str:
                hit = value == ref if not numeric else (not quoted and value == text)
                return hit if want else not hit
            if kind is int or kind is float:
                hit = numeric and value == ref
                return hit if want else not hit
            return general(entity)
        return equality
    return general


def _matches(statement: Statement, entity: Mapping[str, Any], metadata: bool) -> bool:
    value = _target(entity, statement.path, metadata)
    op = statement.op
    if op == "exists":
        return value is not _MISSING
    if op == "absent":
        return value is _MISSING
    if value is _MISSING:
        return False
    if op in ("==", "!="):
        if statement.low is not None and statement.high is not None:
            hit = _between(statement.low, statement.high, value)
        else:
            hit = any(_equal(lit, value) for lit in statement.values)
        return hit if op == "==" else not hit
    if op == "~=":
        assert statement.pattern is not None
        return isinstance(value, str) and statement.pattern.search(value) is not None
    return _order(op, statement.values[0], value)


__all__ = ["Literal", "NgsiError", "Query", "Statement", "parse_q"]
