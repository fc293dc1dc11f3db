"""The triples an edit of one plant file removes and adds, without re-reading the whole file.

Parsing a 100k-resource plant takes ~6 s; a one-line edit changes a few triples. For a Turtle or
N-Triples file whose every string is on one line, whose IRIs are absolute and whose prefixes did
not change, :func:`turtle_delta` cuts out the statements the edit touched (a statement ends on a
line whose last token is ``.``; the statements around an edit are found from the first and last
byte that differ), parses the old and the new cut with the file's prefixes, and compares. A
triple the old cut asserted and the new one does not is removed only if no other statement of the
file asserts it (the statements whose subject is its subject are found by their spelling and
parsed too). Anything it cannot decide exactly — blank nodes or lists in the cut, a changed prefix,
a parse error, a subject spelled in a way it cannot search for — answers None, and
:func:`graph_delta` parses the whole new file and compares graphs instead (slow, exact, and the
path that reports a syntax error as loading does).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import pyoxigraph as ox

from kg.load import format_for

Triple = tuple[ox.NamedNode | ox.BlankNode, ox.NamedNode, ox.NamedNode | ox.BlankNode | ox.Literal]

_STRIP = re.compile(rb'"(?:[^"\\\n]|\\.)*"|\'(?:[^\'\\\n]|\\.)*\'|<[^<>"{}|^`\\\s]*>|#[^\n]*')
_DIRECTIVE = re.compile(rb"(?im)^[ \t]*(?:@prefix|@base|prefix|base)\b[^\n]*$")
_RELATIVE = re.compile(rb"<(?![A-Za-z][A-Za-z0-9+.\-]*:)")
_LOCAL = re.compile(r"[A-Za-z0-9_][A-Za-z0-9_.:-]*")
_CHUNK = 1 << 16
#: More statement starts than this to re-read for one subject: re-parse the file instead.
MAX_STATEMENTS = 2000


@dataclass(frozen=True)
class Delta:
    """Triples an edit removes from and adds to one file's graph; ``how`` says which path found
    them ("cut": the edited statements only, "file": the whole file re-parsed)."""

    removed: tuple[Triple, ...]
    added: tuple[Triple, ...]
    how: str


@dataclass(frozen=True)
class FileText:
    """A plant file's bytes as last read, its prefix/base directives, and whether its edits can
    be read from the edited statements (no multi-line string, no relative IRI, no @base)."""

    data: bytes
    directives: tuple[bytes, ...]
    cuttable: bool

    @classmethod
    def read(cls, path: Path, data: bytes | None = None) -> "FileText":
        data = path.read_bytes() if data is None else data
        directives = tuple(_DIRECTIVE.findall(data))
        cuttable = (format_for(path) in (ox.RdfFormat.TURTLE, ox.RdfFormat.N_TRIPLES)
                    and _cuttable(data)
                    and not any(d.strip().lower().startswith((b"@base", b"base")) for d in directives))
        return cls(data, directives, cuttable)


def _cuttable(data: bytes) -> bool:
    return b'"""' not in data and b"'''" not in data and _RELATIVE.search(data) is None


def _common_prefix(a: bytes, b: bytes) -> int:
    n = min(len(a), len(b))
    i = 0
    while i < n and a[i:i + _CHUNK] == b[i:i + _CHUNK]:
        i += _CHUNK
    end = min(i + _CHUNK, n)
    while i < end and a[i] == b[i]:
        i += 1
    return min(i, n)


def _common_suffix(a: bytes, b: bytes, limit: int) -> int:
    n = min(len(a), len(b), limit)
    i = 0
    while i < n:
        size = min(_CHUNK, n - i)
        if a[len(a) - i - size:len(a) - i] != b[len(b) - i - size:len(b) - i]:
            break
        i += size
    else:
        return n
    while i < n and a[len(a) - i - 1] == b[len(b) - i - 1]:
        i += 1
    return i


def edited_bytes(old: bytes, new: bytes) -> int:
    """The bytes of the longer text between the two texts' common beginning and common end: what
    an edit touched at most, found without parsing."""
    p = _common_prefix(old, new)
    s = _common_suffix(old, new, min(len(old), len(new)) - p)
    return max(len(old), len(new)) - p - s


def _significant(line: bytes) -> bytes:
    return _STRIP.sub(b'""', line).strip()


def _ends_statement(line: bytes) -> bool:
    text = _significant(line)
    return text.endswith(b".") or _DIRECTIVE.match(line) is not None


def _statement_start(text: bytes, pos: int) -> int:
    """Start of the line holding ``pos``, moved back until the line before ends a statement."""
    start = text.rfind(b"\n", 0, pos) + 1
    while start > 0:
        prev = text.rfind(b"\n", 0, start - 1) + 1
        if _ends_statement(text[prev:start - 1]):
            break
        start = prev
    return start


def _statement_end(text: bytes, pos: int) -> int:
    """End (past the newline) of the first line, from the one holding ``pos`` on, that ends a
    statement."""
    pos = text.rfind(b"\n", 0, pos) + 1
    while pos < len(text):
        nl = text.find(b"\n", pos)
        end = len(text) if nl < 0 else nl + 1
        if _ends_statement(text[pos:end]):
            return end
        pos = end
    return len(text)


def _parse(header: bytes, body: bytes, base: str) -> set[Triple] | None:
    try:
        return {(q.subject, q.predicate, q.object)
                for q in ox.parse(input=header + b"\n" + body, format=ox.RdfFormat.TURTLE, base_iri=base)}
    except (SyntaxError, ValueError):
        return None


def turtle_delta(path: Path, old: FileText, new: bytes) -> tuple[Delta, FileText] | None:
    """The edit ``old`` → ``new`` of the Turtle/N-Triples file ``path`` read from the edited
    statements only, and the new :class:`FileText`; None when that cannot be decided exactly
    (see the module doc). Only the cut is searched for what would forbid it: the rest of the
    file is the old text, already known to allow it."""
    if not old.cuttable:
        return None
    text = old.data
    if text == new:
        return Delta((), (), "cut"), old
    p = _common_prefix(text, new)
    s = _common_suffix(text, new, min(len(text), len(new)) - p)
    a = _statement_start(text, p)
    e_old, e_new = len(text) - s, len(new) - s
    while True:
        e_old = _statement_end(text, max(a, e_old - 1))
        e_new = _statement_end(new, max(a, e_new - 1))
        t_old, t_new = len(text) - e_old, len(new) - e_new
        if t_old == t_new:
            break
        t = min(t_old, t_new)
        e_old, e_new = len(text) - t, len(new) - t
    cut_old, cut_new = text[a:e_old], new[a:e_new]
    if not _cuttable(cut_new):
        return None
    for cut in (cut_old, cut_new):
        flat = _STRIP.sub(b'""', cut)
        if b"_:" in flat or b"[" in flat or b"(" in flat or _DIRECTIVE.search(cut):
            return None
    header = b"\n".join(old.directives)
    base = path.resolve().as_uri()
    before, after = _parse(header, cut_old, base), _parse(header, cut_new, base)
    if before is None or after is None:
        return None
    removed, added = before - after, after - before
    elsewhere = _asserted_elsewhere({t[0] for t in removed}, new, (a, e_new), header, base)
    if elsewhere is None:
        return None
    removed -= elsewhere
    delta = Delta(tuple(sorted(removed, key=str)), tuple(sorted(added, key=str)), "cut")
    return delta, FileText(new, old.directives, True)


def _spellings(iri: str, header: bytes) -> list[bytes] | None:
    out = [f"<{iri}>".encode()]
    for m in re.finditer(rb"(?i)(?:@prefix|prefix)\s+([A-Za-z][\w.-]*)?:\s*<([^>]*)>", header):
        name, ns = (m.group(1) or b"").decode(), m.group(2).decode()
        if ns and iri.startswith(ns):
            local = iri[len(ns):]
            if local and (not _LOCAL.fullmatch(local) or local.endswith(".")):
                return None  # a local name the file may have escaped: cannot search for it
            out.append(f"{name}:{local}".encode())
    return out


def _asserted_elsewhere(subjects: set[object], text: bytes, cut: tuple[int, int], header: bytes,
                        base: str) -> set[Triple] | None:
    """Triples with one of ``subjects`` that statements outside ``cut`` assert (None: give up)."""
    found: set[Triple] = set()
    for subject in subjects:
        if not isinstance(subject, ox.NamedNode):
            return None
        spellings = _spellings(subject.value, header)
        if spellings is None:
            return None
        starts: set[int] = set()
        for spelling in spellings:
            for at in _statement_starts(text, spelling):
                if cut[0] <= at < cut[1]:
                    continue
                starts.add(_statement_start(text, at))
                if len(starts) > MAX_STATEMENTS:
                    return None
        for start in starts:
            body = text[start:_statement_end(text, start)]
            triples = _parse(header, body, base)
            if triples is None:
                return None
            found |= {t for t in triples if t[0] == subject}
    return found


def _statement_starts(text: bytes, spelling: bytes):  # noqa: ANN202 - a generator of offsets
    """Offsets where ``spelling`` may start a statement: a whole term, with only blanks between
    it and the line start or a ``.`` before it (a plain search; most hits are objects, skipped)."""
    pos = text.find(spelling)
    while pos >= 0:
        after = pos + len(spelling)
        if after >= len(text) or text[after:after + 1] in b" \t\r\n;,.":
            before = pos
            while before > 0 and text[before - 1:before] in b" \t":
                before -= 1
            if before == 0 or text[before - 1:before] in b"\n.":
                yield pos
        pos = text.find(spelling, after)


def graph_delta(store: ox.Store, graph: ox.NamedNode, path: Path) -> Delta:
    """The edit read by parsing the whole new file and comparing it with ``graph`` (raises the
    loader's errors for a file that cannot be parsed)."""
    from kg.load import _parse_into  # noqa: PLC0415 - the loader's own parsing and error messages

    scratch = ox.Store()
    tmp = ox.NamedNode("urn:plantkg:scratch")
    _parse_into(scratch, path, tmp)
    new = {(q.subject, q.predicate, q.object) for q in scratch.quads_for_pattern(None, None, None, tmp)}
    old = {(q.subject, q.predicate, q.object) for q in store.quads_for_pattern(None, None, None, graph)}
    return Delta(tuple(sorted(old - new, key=str)), tuple(sorted(new - old, key=str)), "file")
