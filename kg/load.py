"""Load plant files into one store, each file in a named graph of its own.

Why Oxigraph and named graphs: Oxigraph parses a 10k-resource plant in about a third of a second
(rdflib needs over four) and answers SPARQL without rdflib's quadratic OPTIONAL/GROUP BY path; and a
graph per file means every triple remembers the file it came from, so an error about a node can
name that file. The ontology is always loaded too (graph ``GRAPH_ONTOLOGY``: every TBox file,
``ontology/*.ttl`` — the ontology and its rules — not the examples), so queries and shapes see class
hierarchies and the reasoner sees the rules. Queries read the union of all graphs.

Nothing is half-loaded: every file is parsed into a scratch store first; only when all parse does
the caller get a :class:`PlantGraph`.
"""

from __future__ import annotations

import hashlib
import re
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

import pyoxigraph as ox

from kg import resources
from kg.errors import InputError, NotAPlantError, RdfSyntaxError
from kg.namespaces import GRAPH_ONTOLOGY, PK

#: File extensions and the RDF syntax they are read as.
FORMATS: dict[str, ox.RdfFormat] = {
    ".ttl": ox.RdfFormat.TURTLE,
    ".turtle": ox.RdfFormat.TURTLE,
    ".nt": ox.RdfFormat.N_TRIPLES,
    ".rdf": ox.RdfFormat.RDF_XML,
    ".owl": ox.RdfFormat.RDF_XML,
    ".xml": ox.RdfFormat.RDF_XML,
    ".jsonld": ox.RdfFormat.JSON_LD,
    ".json": ox.RdfFormat.JSON_LD,
}

_SNIFF_BYTES = 8192
_OX_POSITION = re.compile(r"^Parser error (?:at|between) line[^:]*: ")
_OX_LINE_SUFFIX = re.compile(r" \(line \d+\)$")
_PREFIX_DECL = re.compile(rb"(?im)^\s*(?:@prefix|PREFIX)\s+([A-Za-z][\w.-]*)?:\s*<([^>\s]*)>")


@dataclass(frozen=True)
class Source:
    """One loaded file: where it is, how it was read, its named graph, how many triples."""

    path: Path
    format: str
    graph: str
    triples: int
    prefixes: tuple[tuple[str, str], ...] = ()


@dataclass
class PlantGraph:
    """The merged plant: an Oxigraph store with one named graph per file plus the ontology."""

    store: ox.Store
    sources: tuple[Source, ...]
    ontology: Source
    extra_graphs: dict[str, str] = field(default_factory=dict)
    #: Every TBox file loaded into the ontology graph (``ontology`` is the first of them).
    tbox: tuple[Source, ...] = ()
    #: SHA-256 of the TBox files' paths and bytes as loaded (None: not known); what depends only
    #: on the TBox is kept per process under it (engine.reasoning.tbox_cache).
    tbox_digest: str | None = None

    @property
    def plant_graphs(self) -> list[ox.NamedNode]:
        """The named graphs holding the plant files (not the ontology)."""
        return [ox.NamedNode(s.graph) for s in self.sources]

    @property
    def prefixes(self) -> dict[str, str]:
        """Prefixes declared by the files (for display only; queries get the standard ones)."""
        out: dict[str, str] = {}
        for src in (self.ontology, *self.tbox, *self.sources):
            for name, ns in src.prefixes:
                out.setdefault(name, ns)
        return out

    @property
    def triple_count(self) -> int:
        """Triples of the plant files (the ontology not counted)."""
        return sum(s.triples for s in self.sources)

    def source_of(self, node: ox.NamedNode | ox.BlankNode) -> Path | None:
        """The file in which ``node`` is the subject of a triple (first one found), if any."""
        for quad in self.store.quads_for_pattern(node, None, None, None):
            for src in self.sources:
                if quad.graph_name == ox.NamedNode(src.graph):
                    return src.path
        return None

    def iter_plant_quads(self) -> Iterable[ox.Quad]:
        """Every quad of the plant files."""
        for g in self.plant_graphs:
            yield from self.store.quads_for_pattern(None, None, None, g)


def format_for(path: Path) -> ox.RdfFormat:
    """The RDF syntax of ``path``, decided by its extension."""
    fmt = FORMATS.get(path.suffix.lower())
    if fmt is None:
        known = ", ".join(sorted(FORMATS))
        raise InputError(
            path,
            f"unknown file extension {path.suffix or '(none)'!r}",
            hint=f"name the file with one of {known}",
        )
    return fmt


def _declared_prefixes(path: Path) -> tuple[tuple[str, str], ...]:
    """Prefixes a Turtle file declares near its top (used to print short names)."""
    if format_for(path) != ox.RdfFormat.TURTLE:
        return ()
    with path.open("rb") as fh:
        head = fh.read(65536)
    return tuple(
        (m.group(1).decode() if m.group(1) else "", m.group(2).decode("utf-8", "replace"))
        for m in _PREFIX_DECL.finditer(head)
    )


def _check_readable(path: Path) -> None:
    if not path.exists():
        raise InputError(path, "no such file", hint="check the path and the current directory")
    if path.is_dir():
        raise InputError(
            path, "is a directory, not a plant file", hint=f"pass the files in it, e.g. {path}/*.ttl"
        )
    if not path.is_file():
        raise InputError(path, "is not a regular file")
    try:
        with path.open("rb") as fh:
            head = fh.read(_SNIFF_BYTES)
    except OSError as exc:
        raise InputError(path, f"cannot be read: {exc.strerror}") from exc
    if b"\x00" in head:
        raise InputError(
            path,
            "is a binary file, not RDF text",
            hint="plant files are Turtle (.ttl), N-Triples, RDF/XML or JSON-LD text",
        )


def _line_of(path: Path, line: int | None) -> str:
    if line is None or line < 1:
        return ""
    with path.open("rb") as fh:
        for number, raw in enumerate(fh, start=1):
            if number == line:
                return raw.decode("utf-8", errors="replace").rstrip("\r\n")
    return ""


def _syntax_error(path: Path, exc: SyntaxError) -> RdfSyntaxError:
    problem = _OX_LINE_SUFFIX.sub("", _OX_POSITION.sub("", str(exc.msg if exc.msg else exc)))
    line = exc.lineno
    column = exc.offset
    return RdfSyntaxError(path, line, column, problem, _line_of(path, line))


def _parse_into(store: ox.Store, path: Path, graph: ox.NamedNode, data: bytes | None = None) -> int:
    """Parse ``path`` (or ``data``, its bytes already read) into ``graph``; the triples added."""
    fmt = format_for(path)
    before = len(store)
    try:
        if data is None:
            store.load(path=str(path), format=fmt, base_iri=path.resolve().as_uri(), to_graph=graph)
        else:
            store.load(data, format=fmt, base_iri=path.resolve().as_uri(), to_graph=graph)
    except SyntaxError as exc:
        raise _syntax_error(path, exc) from None
    except (OSError, ValueError) as exc:
        raise InputError(path, f"cannot be loaded: {exc}") from None
    return len(store) - before


def _uses_plantkg_terms(store: ox.Store, graph: ox.NamedNode) -> bool:
    ns = ox.Literal(str(PK))  # constants written as terms serialised by Oxigraph
    query = f"ASK {{ GRAPH {graph} {{ ?s ?p ?o FILTER(STRSTARTS(STR(?p), {ns}) || STRSTARTS(STR(?o), {ns})) }} }}"
    return bool(store.query(query))


#: The parsed TBox per digest of its files (paths and bytes): parsed once per process.
_TBOXES: dict[str, tuple[list[ox.Quad], tuple[Source, ...]]] = {}
_TBOXES_KEPT = 4
_tbox_lock = threading.Lock()


def _load_tbox(store: ox.Store, paths: list[Path]) -> tuple[tuple[Source, ...], str | None]:
    """Load the TBox files into the ontology graph of the (empty) ``store``; their sources and
    the SHA-256 of what was loaded (None if a file could not be read: the parser then says why).
    Parsed once per process while the files' bytes are the same (a long-running process plans
    again and again); later loads copy the parsed triples, about three times faster."""
    try:
        contents = [p.read_bytes() for p in paths]
    except OSError:
        contents = None
    if contents is None:
        graph = ox.NamedNode(GRAPH_ONTOLOGY)
        return tuple(Source(p, format_for(p).name, GRAPH_ONTOLOGY, _parse_into(store, p, graph),
                            _declared_prefixes(p)) for p in paths), None
    digest = hashlib.sha256()
    for path, data in zip(paths, contents):
        digest.update(str(path.resolve()).encode() + b"\0" + data + b"\0")
    key = digest.hexdigest()
    kept = _TBOXES.get(key)
    if kept is not None:
        store.bulk_extend(kept[0])
        return kept[1], key
    graph = ox.NamedNode(GRAPH_ONTOLOGY)
    tbox = tuple(Source(p, format_for(p).name, GRAPH_ONTOLOGY, _parse_into(store, p, graph, data),
                        _declared_prefixes(p)) for p, data in zip(paths, contents))
    with _tbox_lock:
        if len(_TBOXES) >= _TBOXES_KEPT:
            _TBOXES.pop(next(iter(_TBOXES)))
        _TBOXES[key] = (list(store.quads_for_pattern(None, None, None, graph)), tbox)
    return tbox, key


def load_plant(paths: Iterable[Path | str], *, ontology: Path | None = None) -> PlantGraph:
    """Parse ``paths`` (and the ontology) into one :class:`PlantGraph`.

    ``ontology`` replaces the TBox files (``ontology/*.ttl`` and those of plugin packages,
    :func:`kg.resources.tbox_files`) with that one file.

    Raises :class:`InputError` (or its :class:`RdfSyntaxError`) naming the file, line and column
    for a file that cannot be used, and :class:`NotAPlantError` when nothing describes a plant.
    """
    files = [Path(p) for p in paths]
    if not files:
        raise InputError("(no files)", "no plant file given", hint="pass one or more .ttl files")
    store = ox.Store()
    tbox, tbox_digest = _load_tbox(store, [ontology] if ontology is not None else resources.tbox_files())
    onto = tbox[0]
    sources: list[Source] = []
    seen: set[Path] = set()
    for path in files:
        _check_readable(path)
        resolved = path.resolve()
        if resolved in seen:
            continue
        seen.add(resolved)
        graph = ox.NamedNode(resolved.as_uri())
        count = _parse_into(store, path, graph)
        if count == 0:
            raise InputError(path, "holds no triples", hint="an empty plant deploys nothing; add resources and brokers")
        sources.append(Source(path, format_for(path).name, graph.value, count, _declared_prefixes(path)))
    if not any(_uses_plantkg_terms(store, ox.NamedNode(s.graph)) for s in sources):
        names = ", ".join(str(s.path) for s in sources)
        raise NotAPlantError(
            f"{names}: uses no term of the plantkg ontology ({PK})",
            hint="declare `@prefix pk: <https://w3id.org/plantkg/ontology#> .` and type "
            "individuals as pk:Resource, pk:Broker, pk:Topic, ...",
        )
    return PlantGraph(store=store, sources=tuple(sources), ontology=onto, tbox=tbox, tbox_digest=tbox_digest)
