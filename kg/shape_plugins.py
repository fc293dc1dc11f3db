"""Shapes and ontology terms that installed packages bring, and the broker types the installed drivers allow.

A broker type is a driver package (entry-point group ``plantkg.drivers``, name = the
``pk:brokerType`` value; see docs/drivers.md). So that a plant may ask for it without an edit of
plantkg, the shapes accept every *registered* driver name, not a list written in
``shapes/plantkg-shapes.ttl``: :func:`with_broker_types` rewrites the ``sh:in`` list of every
property shape on ``pk:brokerType`` to the registered names, and its message to name them. A package
may also bring shapes of its own (its topic settings, say) through the entry-point group
``plantkg.shapes``: name = anything unique, value = a package whose ``*.ttl`` files are shapes,
added to the project's shapes by :func:`kg.validate.load_default_shapes`. Ontology terms come the
same way, through ``plantkg.ontology`` (value = a package whose ``*.ttl`` files are TBox files,
loaded beside ``ontology/*.ttl`` by :func:`kg.resources.tbox_files`): a broker type's own class,
say, declared a subclass of ``pk:MqttBroker`` so the rules and the bridge planner treat it as one.

Only entry-point *names* and package resources are read here — no driver is imported, and kg never
imports engine. With only the built-in drivers installed, the shapes are left exactly as written.
The entry points are read once per process (scanning the installed packages took ~25 ms, paid by
every validation otherwise): a package installed later counts after a restart, as for the agent's
drivers, or after :func:`forget_entry_points`.
"""

from __future__ import annotations

from collections.abc import Iterable
from functools import lru_cache
from importlib.metadata import EntryPoint, entry_points
from importlib.resources import files as package_files
from pathlib import Path

from rdflib import BNode, Graph, Literal
from rdflib.collection import Collection
from rdflib.term import Node

from kg.errors import ShapesError
from kg.namespaces import PK, SH

DRIVERS_GROUP = "plantkg.drivers"
SHAPES_GROUP = "plantkg.shapes"
ONTOLOGY_GROUP = "plantkg.ontology"


def registered_broker_types(group: str = DRIVERS_GROUP) -> tuple[str, ...]:
    """The names of the installed driver entry points, sorted (no driver is loaded)."""
    return tuple(sorted({ep.name for ep in _entry_points(group)}))


def plugin_shapes_files(group: str = SHAPES_GROUP) -> list[Path]:
    """The shapes files installed packages declare: every ``*.ttl`` of each entry point's package
    (value = a package name, e.g. ``plantkg_x.shapes``), by entry-point name, then file name.

    A package that cannot be found or holds no ``.ttl`` is a :class:`~kg.errors.ShapesError`
    naming the entry point: validating without a plugin's shapes would let its plants through
    unchecked.
    """
    return _package_ttl_files(group)


def plugin_ontology_files(group: str = ONTOLOGY_GROUP) -> list[Path]:
    """The TBox files installed packages declare (group ``plantkg.ontology``), found and ordered as
    :func:`plugin_shapes_files`; a package that cannot be read is a :class:`~kg.errors.ShapesError`
    too: reasoning without a plugin's terms would misclassify its brokers."""
    return _package_ttl_files(group)


def _package_ttl_files(group: str) -> list[Path]:
    out: list[Path] = []
    for ep in sorted(_entry_points(group), key=lambda e: e.name):
        where = f"entry point {ep.name!r} = {ep.value!r} of group {group!r}"
        hint = "reinstall the package that declares it, or uninstall it"
        if ep.attr:
            raise ShapesError(f"{where} names an attribute; its value must be a package holding .ttl files",
                              hint=hint)
        try:
            folder = package_files(ep.module)
        except Exception as exc:  # noqa: BLE001 - importing a third-party package may fail in any way
            raise ShapesError(f"{where}: cannot import the package ({type(exc).__name__}: {exc})", hint=hint) from None
        found = sorted(Path(str(f)) for f in folder.iterdir() if f.name.endswith(".ttl") and f.is_file())
        if not found:
            raise ShapesError(f"{where}: no .ttl file in {folder}", hint=hint)
        out.extend(found)
    return out


def forget_entry_points() -> None:
    """Read the entry points again on next use (a package was installed or removed meanwhile)."""
    _entry_points.cache_clear()


@lru_cache(maxsize=8)
def _entry_points(group: str) -> tuple[EntryPoint, ...]:
    return tuple(entry_points(group=group))


def with_broker_types(graph: Graph, kinds: Iterable[str]) -> Graph:
    """``graph`` with every ``sh:in`` on ``pk:brokerType`` set to ``kinds`` (in place, returned).

    Shapes whose list already holds exactly ``kinds`` keep their own message; the others get one
    that names the allowed values. No ``kinds`` (no driver installed, e.g. a bare checkout): the
    shapes are left as written.
    """
    allowed = sorted(set(kinds))
    if not allowed:
        return graph
    for shape in set(graph.subjects(SH.path, PK.brokerType)):
        for head in list(graph.objects(shape, SH["in"])):
            if sorted(str(v) for v in Collection(graph, head)) == allowed:
                continue
            _replace_list(graph, shape, head, allowed)
            graph.remove((shape, SH.message, None))
            graph.add((shape, SH.message, Literal(unknown_type_message(allowed))))
    return graph


def unknown_type_message(allowed: list[str]) -> str:
    """The message of an unknown ``pk:brokerType`` naming the installed drivers."""
    names = ", ".join(allowed[:-1]) + f" and {allowed[-1]}" if len(allowed) > 1 else allowed[0]
    return (f"Unknown pk:brokerType: the installed drivers are {names}. Write one of them, in lower "
            "case, as a plain string, or install the package of the broker type you need.")


def _replace_list(graph: Graph, shape: Node, head: Node, values: list[str]) -> None:
    Collection(graph, head).clear()
    graph.remove((shape, SH["in"], head))
    new = BNode()
    Collection(graph, new, [Literal(v) for v in values])
    graph.add((shape, SH["in"], new))
