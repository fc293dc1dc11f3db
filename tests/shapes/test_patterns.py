"""The regular expressions and string tricks of the shapes mean the same in both engines.

pySHACL evaluates sh:pattern and SPARQL REGEX with Python's ``re``; the fast engine runs them in
Oxigraph, i.e. Rust's ``regex`` crate. Here every pattern of shapes/*.ttl is run by both over a
corpus of awkward strings, the IP address pattern is checked against Python's ``ipaddress``, and
the SPARQL expressions that count UTF-8 bytes and find control characters are checked against
plain Python definitions, in rdflib and in Oxigraph.

The one known difference: Python's ``$`` also matches just before a final newline, Rust's does not.
Strings ending in a newline are left out of the pattern comparison; the shapes deal with them
(see the header of shapes/plantkg-shapes.ttl and the case broker-ip-trailing-newline).
"""

from __future__ import annotations

import ipaddress
import random
import re
from pathlib import Path

import pyoxigraph as ox
import pytest
from rdflib import Graph
from rdflib.namespace import SH

ROOT = Path(__file__).resolve().parents[2]
SHAPES = sorted((ROOT / "shapes").glob("*.ttl"))
PKS = "https://w3id.org/plantkg/shapes#"


def _shapes() -> Graph:
    g = Graph()
    for f in SHAPES:
        g.parse(f, format="turtle")
    return g


def _patterns() -> dict[str, str]:
    """Every regex of the shapes: sh:pattern values and the constant patterns of REGEX/REPLACE."""
    g = _shapes()
    out = {f"{s} sh:pattern": str(p) for s, p in g.subject_objects(SH.pattern)}
    for shape, constraint in g.subject_objects(SH.sparql):
        text = str(g.value(constraint, SH.select))
        for i, m in enumerate(re.finditer(r'(?:REGEX|REPLACE)\([^"]*"([^"]*)"', text)):
            out[f"{shape} #{i}"] = m.group(1)
    return out


PATTERNS = _patterns()

CORPUS = [
    "", "a", "A-z_0.9", ".", "..", "...", "a b", "a/b", "a+b", "a#b", "$SYS/x", "é", "énergie", "日本",
    "\U0001f600", "x" * 300, "127.0.0.1", "255.255.255.255", "256.0.0.1", "01.2.3.4", "1.2.3",
    "::1", "::", "1::2::3", "fe80::1%eth0", "[::1]", "::ffff:1.2.3.4", "2001:db8::ff00:42:8329",
    "1:2:3:4:5:6:7:8", "1:2:3:4:5:6:7:8:9", "6", "+6", "-6", "6.", ".5", "6.5", "1.5e3", "1E-3", "INF",
    "-INF", "NaN", "nan", "true", "false", "1", "0", "yes", "True", "2023-05-01T08:00:00Z",
    "2023-05-01T08:00:00.123+02:00", "2023-13-01T08:00:00Z", "2023-05-01", "24:00:00",
    "2023-05-01T24:00:00", "a\tb", "a\rb", "a\nb", "\nabc", "a\x00b", "a\x7fb", "a\x85b", "a\u2028b",
    "%41", "%zz", "ab%", "robot1", "robot 1/a", "_x", "-x", "p" * 128, "p" * 129,
]


def _ox_regex(strings: list[str], pattern: str) -> list[bool]:
    store = ox.Store()
    values = " ".join(str(ox.Literal(s)) for s in strings)
    query = f"SELECT ?s (REGEX(?s, {ox.Literal(pattern)}) AS ?m) WHERE {{ VALUES ?s {{ {values} }} }}"
    got = {row["s"].value: row["m"].value == "true" for row in store.query(query)}
    return [got[s] for s in strings]


@pytest.mark.parametrize("where", sorted(PATTERNS), ids=lambda w: w.replace(PKS, "pks:"))
def test_python_and_rust_agree(where: str) -> None:
    pattern = PATTERNS[where]
    strings = [s for s in CORPUS if not s.endswith("\n")]
    python = [re.search(pattern, s) is not None for s in strings]
    rust = _ox_regex(strings, pattern)
    differ = [s for s, p, r in zip(strings, python, rust) if p != r]
    assert not differ, f"{where}: Python and Rust regex disagree on {differ!r}"


def _ip_pattern() -> str:
    (pattern,) = [p for w, p in PATTERNS.items() if w.startswith(PKS + "Broker-ipValue")]
    return pattern


def _is_ip(s: str) -> bool:
    if "%" in s:  # zone ids are refused on purpose
        return False
    try:
        ipaddress.ip_address(s)
        return True
    except ValueError:
        return False


def _ip_candidates(n: int, seed: int) -> set[str]:
    """Random IPv4/IPv6 texts, valid and not: group counts around 8, '::' anywhere, IPv4 tails."""
    rng = random.Random(seed)
    out: set[str] = set(CORPUS)
    for _ in range(n):
        out.add(str(ipaddress.IPv4Address(rng.getrandbits(32))))
        a = ipaddress.IPv6Address(rng.getrandbits(128))
        out.update([a.compressed, a.exploded, a.exploded.upper()])
        out.add(".".join(rng.choice(["0", "1", "09", "99", "199", "255", "256", "300", "-1", "00", ""])
                         for _ in range(rng.choice([3, 4, 5]))))
        v4 = rng.random() < 0.4
        total = 6 if v4 else 8
        groups = [rng.choice(["0", "1", "ab", "FFFF", "1234", "0db8", "12345", "g1"])
                  for _ in range(rng.randint(0, total + 1))]
        text = ":".join(groups)
        if rng.random() < 0.7 and len(groups) <= total:
            k = rng.randint(0, len(groups))
            text = ":".join(groups[:k]) + "::" + ":".join(groups[k:])
        if v4:
            text += (":" if text and not text.endswith(":") else "") + rng.choice(["1.2.3.4", "255.0.0.1", "256.1.1.1"])
        out.add(text)
    return out


def test_ip_pattern_matches_exactly_the_addresses_ipaddress_accepts() -> None:
    pattern = re.compile(_ip_pattern())
    candidates = sorted(_ip_candidates(20000, seed=11))
    assert sum(map(_is_ip, candidates)) > 20000  # the corpus holds many valid addresses too
    wrong = [s for s in candidates if (pattern.search(s) is not None) != _is_ip(s)]
    assert not wrong, wrong[:20]


def test_ip_pattern_rust_agrees_on_random_addresses() -> None:
    pattern = _ip_pattern()
    candidates = sorted(_ip_candidates(1500, seed=12))
    rust = _ox_regex(candidates, pattern)
    wrong = [s for s, r in zip(candidates, rust) if r != _is_ip(s)]
    assert not wrong, wrong[:20]


def _both_engines(expression: str, strings: list[str]) -> tuple[list[str], list[str]]:
    """``expression`` over ?s for each string, evaluated by rdflib and by Oxigraph (as text)."""
    values = " ".join(str(ox.Literal(s)) for s in strings)
    query = f"SELECT ?s ({expression} AS ?x) WHERE {{ VALUES ?s {{ {values} }} }}"
    ox_rows = {row["s"].value: row["x"].value for row in ox.Store().query(query)}
    rdflib_rows = {str(s): str(x) for s, x in Graph().query(query)}
    return [rdflib_rows[s] for s in strings], [ox_rows[s] for s in strings]


UTF8_BYTES = 'STRLEN(REPLACE(ENCODE_FOR_URI(STR(?s)), "%[0-9A-F]{2}", "x"))'
CONTROL = 'REGEX(ENCODE_FOR_URI(STR(?s)), "%(0[0-9A-F]|1[0-9A-F]|7F|C2%[89][0-9A-F]|E2%80%A[89])")'


def test_the_shapes_use_these_expressions() -> None:
    text = (ROOT / "shapes" / "plantkg-shapes.ttl").read_text(encoding="utf-8")
    assert UTF8_BYTES.replace("?s", "?value") in text
    assert CONTROL.replace("?s", "?value") in text


def test_utf8_byte_count() -> None:
    strings = ["", "a", "é", "日本", "\U0001f600", "a b/c", "%", "%41", "\x00", "~-._", "x" * 70, "é" * 40]
    want = [str(len(s.encode("utf-8"))) for s in strings]
    by_rdflib, by_oxigraph = _both_engines(UTF8_BYTES, strings)
    assert by_rdflib == want
    assert by_oxigraph == want


def test_control_character_expression() -> None:
    chars = [chr(c) for c in range(0x0, 0x300) if not 0xD800 <= c <= 0xDFFF]
    chars += ["\u2027", "\u2028", "\u2029", "\u202a", "\ufeff", "\U0001f600"]
    strings = [f"a{c}b" for c in chars]

    def is_control(c: str) -> bool:
        o = ord(c)
        return o < 0x20 or o == 0x7F or 0x80 <= o <= 0x9F or o in (0x2028, 0x2029)

    want = ["true" if is_control(c) else "false" for c in chars]
    by_rdflib, by_oxigraph = _both_engines(CONTROL, strings)
    assert by_rdflib == want
    assert by_oxigraph == want

