"""Turn reports and query answers into text for people (table, coloured) and for programs.

Colour is added with ``click.style``; ``click.echo`` drops it when the output is not a terminal, so
piped output is plain without a flag. JSON follows the SPARQL 1.1 Query Results JSON Format for
SELECT/ASK; CSV follows SPARQL 1.1 CSV results (plain values).
"""

from __future__ import annotations

import csv
import io
import json
from typing import Mapping

import click
import pyoxigraph as ox

from kg.namespaces import PREFIXES
from kg.query import QueryResult, Term
from kg.validate import ValidationReport, ValidationResult

_SEVERITY_STYLE = {"Violation": ("red", "✗"), "Warning": ("yellow", "!"), "Info": ("blue", "i")}


class Compactor:
    """Shortens IRIs with known prefixes: ``https://w3id.org/plantkg/ontology#port`` → ``pk:port``."""

    def __init__(self, prefixes: Mapping[str, str] | None = None) -> None:
        merged = {**(prefixes or {}), **PREFIXES}
        self._by_length = sorted(((ns, p) for p, ns in merged.items() if ns), key=lambda x: -len(x[0]))

    def iri(self, iri: str | None) -> str:
        if iri is None:
            return ""
        for ns, prefix in self._by_length:
            if iri.startswith(ns) and iri[len(ns):].replace("-", "").replace("_", "").replace(".", "").isalnum():
                return f"{prefix}:{iri[len(ns):]}"
        return f"<{iri}>" if "://" in iri or iri.startswith("urn:") else iri

    def term(self, t: Term | None) -> str:
        if t is None:
            return ""
        if isinstance(t, ox.NamedNode):
            return self.iri(t.value)
        if isinstance(t, ox.BlankNode):
            return f"_:{t.value}"
        return t.value


def _value_text(value: str | None) -> str:
    if value is None:
        return ""
    shown = value if len(value) <= 60 else value[:57] + "..."
    return json.dumps(shown, ensure_ascii=True) if any(c in shown for c in "\n\r\x00\t\"") else shown


def _result_lines(r: ValidationResult, c: Compactor) -> list[str]:
    colour, mark = _SEVERITY_STYLE.get(r.severity, ("white", "?"))
    head = click.style(f"{mark} {r.severity}", fg=colour, bold=True)
    where = c.iri(r.focus)
    if r.path:
        where += f"  {c.iri(r.path)}"
    if r.value is not None and r.value != r.focus:
        where += f" = {_value_text(c.iri(r.value) if '://' in r.value else r.value)}"
    lines = [f"{head}  {where}", f"    {r.message}"]
    meta = f"shape {c.iri(r.shape)} ({r.component.removesuffix('ConstraintComponent')})"
    if r.file:
        meta += f" · {r.file}"
    lines.append(click.style(f"    {meta}", dim=True))
    return lines


def validation_text(report: ValidationReport, prefixes: Mapping[str, str] | None = None) -> str:
    """A report for people: a summary line, then each result with node, property, value, message."""
    c = Compactor(prefixes)
    files = ", ".join(report.files)
    nv, nw = len(report.violations), len(report.warnings)
    if report.conforms:
        summary = click.style("valid", fg="green", bold=True) + f": {files}"
        if nw:
            summary += f" ({nw} warning{'s' * (nw != 1)})"
    else:
        summary = (click.style("invalid", fg="red", bold=True)
                   + f": {files}: {nv} violation{'s' * (nv != 1)}, {nw} warning{'s' * (nw != 1)}")
    lines = [summary]
    for r in report.results:
        lines.append("")
        lines.extend(_result_lines(r, c))
    return "\n".join(lines)


def validation_json(report: ValidationReport) -> str:
    """The report as JSON (stable keys; see ``ValidationReport.to_dict``)."""
    return json.dumps(report.to_dict(), indent=2, ensure_ascii=False)


def _json_term(t: Term) -> dict[str, str]:
    if isinstance(t, ox.NamedNode):
        return {"type": "uri", "value": t.value}
    if isinstance(t, ox.BlankNode):
        return {"type": "bnode", "value": t.value}
    out = {"type": "literal", "value": t.value}
    if t.language:
        out["xml:lang"] = t.language
    elif t.datatype.value != "http://www.w3.org/2001/XMLSchema#string":
        out["datatype"] = t.datatype.value
    return out


def query_json(result: QueryResult) -> str:
    """SPARQL 1.1 JSON results (SELECT, ASK); JSON-LD for CONSTRUCT/DESCRIBE."""
    if result.kind == "ask":
        return json.dumps({"head": {}, "boolean": result.boolean})
    if result.kind == "construct":
        return ox.serialize(list(result.triples), format=ox.RdfFormat.JSON_LD).decode()
    bindings = [
        {v: _json_term(t) for v, t in zip(result.variables, row) if t is not None}
        for row in result.rows
    ]
    return json.dumps({"head": {"vars": list(result.variables)}, "results": {"bindings": bindings}},
                      indent=1, ensure_ascii=False)


def query_csv(result: QueryResult) -> str:
    """SPARQL 1.1 CSV results; ASK gives one line ``true``/``false``; CONSTRUCT gives N-Triples."""
    if result.kind == "ask":
        return "true" if result.boolean else "false"
    if result.kind == "construct":
        return ox.serialize(list(result.triples), format=ox.RdfFormat.N_TRIPLES).decode().rstrip("\n")
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\r\n")
    writer.writerow(result.variables)
    for row in result.rows:
        writer.writerow(["" if t is None else (f"_:{t.value}" if isinstance(t, ox.BlankNode) else t.value) for t in row])
    return buf.getvalue().rstrip("\r\n")


def query_table(result: QueryResult, prefixes: Mapping[str, str] | None = None) -> str:
    """An aligned table with short names; ASK prints yes/no; CONSTRUCT prints Turtle."""
    c = Compactor(prefixes)
    if result.kind == "ask":
        return "yes" if result.boolean else "no"
    if result.kind == "construct":
        used = {**(prefixes or {}), **PREFIXES}
        return ox.serialize(list(result.triples), format=ox.RdfFormat.TURTLE, prefixes=used).decode().rstrip("\n")
    header = list(result.variables)
    body = [[c.term(t) for t in row] for row in result.rows]
    widths = [max([len(h), *(len(r[i]) for r in body)]) for i, h in enumerate(header)]
    fmt = "  ".join(f"{{:<{w}}}" for w in widths)
    lines = [click.style(fmt.format(*header), bold=True), fmt.format(*("─" * w for w in widths))]
    lines += [fmt.format(*r).rstrip() for r in body]
    lines.append(click.style(f"({len(body)} row{'s' * (len(body) != 1)})", dim=True))
    return "\n".join(lines)
