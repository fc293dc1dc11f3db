"""Does a SHACL-SPARQL ``SELECT`` bind ``?this`` by itself? A conservative reading of its text.

The fast validator joins a constraint's top-level group with the shape's focus nodes (SHACL §5.3,
pre-binding ``$this``). When the group binds ``?this`` in every solution anyway, joining with the
focus nodes is the same as keeping, afterwards, the rows whose ``?this`` is one: the join only
removes rows, and every operator of the group (join, OPTIONAL and MINUS on its right side, BIND,
FILTER) commutes with that removal when ``?this`` is bound on the left. The validator then runs the
query without the focus pattern and filters the (few) violating rows (:mod:`kg.focus`).

"Binds in every solution" is read from the text, conservatively: ``?this`` must be a term of a
triple pattern written directly in the WHERE group (not inside a nested group, OPTIONAL, UNION,
MINUS, sub-query, FILTER, BIND or list) *before* the group's first OPTIONAL, MINUS, BIND, VALUES or
nested group (so the focus join, which sits at the start of the group, meets the same rows either
way), the query must project it, and the query must have no
solution modifier after its WHERE group (GROUP BY, HAVING, ORDER BY, LIMIT, OFFSET, VALUES), no
``GRAPH``, ``SERVICE`` or ``VALUES`` at the top level. Anything else answers False and the focus
pattern is joined as before: a wrong "no" costs time, never a result.
"""

from __future__ import annotations

import re
from functools import lru_cache

_STRING_OR_IRI = re.compile(
    r'"""(?:[^"\\]|\\.|"(?!""))*"""|\'\'\'(?:[^\'\\]|\\.|\'(?!\'\'))*\'\'\''
    r'|"(?:[^"\\\n]|\\.)*"|\'(?:[^\'\\\n]|\\.)*\'|<[^<>"{}|^`\\\s]*>|#[^\n]*')
_TOKEN = re.compile(r"[?$][A-Za-z0-9_]+|[A-Za-z_][A-Za-z0-9_-]*|\*|\S")
_MODIFIERS = {"group", "having", "order", "limit", "offset", "values"}


def _blank_literals(text: str) -> str:
    """``text`` with strings, IRIs and comments replaced by neutral placeholders."""
    def repl(m: re.Match[str]) -> str:
        s = m.group(0)
        return " " if s.startswith("#") else ("<I>" if s.startswith("<") else '"S"')
    return _STRING_OR_IRI.sub(repl, text)


def _skip(text: str, start: int, open_: str, close: str) -> int:
    """Index just past the ``close`` matching the ``open_`` at ``start``; len(text) if none."""
    depth = 0
    for i in range(start, len(text)):
        ch = text[i]
        if ch == open_:
            depth += 1
        elif ch == close:
            depth -= 1
            if depth == 0:
                return i + 1
    return len(text)


@lru_cache(maxsize=4096)
def binds_this(query: str, var: str = "this") -> bool:
    """Whether every solution of ``query``'s WHERE group binds ``?var`` (see the module doc).
    Remembered per text: the shapes' queries are the same at every validation of a process."""
    text = _blank_literals(query)
    brace = text.find("{")
    if brace < 0:
        return False
    head, end = text[:brace], _skip(text, brace, "{", "}")
    if text[end - 1] != "}":
        return False
    tail = text[end:]
    if any(t.lower() in _MODIFIERS for t in _TOKEN.findall(tail)):
        return False
    select = re.search(r"(?i)\bselect\b", head)
    if select is None:
        return False
    projection = _depth0(head[select.end():], "(", ")")
    tokens = _TOKEN.findall(projection)
    if "*" not in tokens and f"?{var}" not in tokens and f"${var}" not in tokens:
        return False
    return _bound_before_any_operator(text[brace + 1:end - 1], var)


def _bound_before_any_operator(body: str, var: str) -> bool:
    """Whether a triple pattern binding ``?var`` comes before the group's first OPTIONAL, MINUS,
    BIND, VALUES, nested group, sub-query, GRAPH or SERVICE (FILTERs apply to the whole group, so
    they may be anywhere). The focus join of the validator sits at the very start of the group:
    removing it commutes with the group's operators only when ``?var`` is bound before them."""
    tokens = _TOKEN.findall(body)
    i = 0
    while i < len(tokens):
        t = tokens[i]
        if t in (f"?{var}", f"${var}"):
            return True
        if t.lower() == "filter":
            i = _skip_filter(tokens, i + 1)
            continue
        if t in ("{", "(") or t.lower() in ("optional", "minus", "bind", "values", "graph", "service", "union"):
            return False
        i += 1
    return False


def _skip_filter(tokens: list[str], i: int) -> int:
    """Index past a FILTER's constraint: ``(...)``, ``name(...)``, ``<iri>(...)`` or
    ``[NOT] EXISTS {...}``; ``len(tokens)`` (stop) when it has another form."""
    if i < len(tokens) and tokens[i].lower() == "not":
        i += 1
    if i < len(tokens) and tokens[i].lower() == "exists":
        return _past(tokens, i + 1, "{", "}")
    if i < len(tokens) and tokens[i] != "(":
        i += 1  # a function name (a built-in, or <iri> blanked to "<", "I", ">")
        while i < len(tokens) and tokens[i] in ("I", ">"):
            i += 1
    return _past(tokens, i, "(", ")")


def _past(tokens: list[str], i: int, open_: str, close: str) -> int:
    if i >= len(tokens) or tokens[i] != open_:
        return len(tokens)
    depth = 0
    for j in range(i, len(tokens)):
        if tokens[j] == open_:
            depth += 1
        elif tokens[j] == close:
            depth -= 1
            if depth == 0:
                return j + 1
    return len(tokens)


def _depth0(text: str, open_: str, close: str) -> str:
    """``text`` with every ``open_ ... close`` group (nested ones included) cut out."""
    out, i = [], 0
    while i < len(text):
        j = text.find(open_, i)
        if j < 0:
            out.append(text[i:])
            break
        out.append(text[i:j] + " ")
        i = _skip(text, j, open_, close)
    return "".join(out)
