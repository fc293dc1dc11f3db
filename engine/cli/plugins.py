"""The plugin commands of ``plantkg`` (entry-point group ``plantkg.commands``), found without
importing :mod:`importlib.metadata`.

Why: ``plantkg --help`` lists the plugin commands, and importing ``importlib.metadata`` (it loads
the ``email`` package) plus its scan of every distribution cost ~40 ms of a start-up that should
stay under 0.15 s (issue 16). Only ``entry_points.txt`` is needed, so this module reads it from the
``*.dist-info`` / ``*.egg-info`` folders of ``sys.path`` in the order and with the precedence
``importlib.metadata.entry_points`` uses (the first distribution of a normalised name wins).
``tests/unit/test_cli_imports.py`` holds the two to the same answer for every group installed.
Zipped eggs are not searched (``importlib.metadata`` reads them; pip has not made them for years).
"""

from __future__ import annotations

import os
import re
import sys
from collections.abc import Iterable
from dataclasses import dataclass
from importlib import import_module
from typing import Any

_METADATA_DIRS = (".dist-info", ".egg-info")
# importlib.metadata.EntryPoint.pattern: module, optional ":attr.attr", optional "[extras]"
_VALUE = re.compile(r"(?P<module>[\w.]+)\s*(:\s*(?P<attr>[\w.]+)\s*)?((?P<extras>\[.*\])\s*)?$")


@dataclass(frozen=True)
class Plugin:
    """One entry point: ``name = value`` in ``group``, ``value`` being ``module:attribute``."""

    name: str
    value: str
    group: str

    def load(self) -> Any:
        """Import the module and return the attribute (as ``EntryPoint.load``)."""
        match = _VALUE.match(self.value)
        if match is None:
            raise ValueError(f"entry point {self.name!r} = {self.value!r} is not 'module:attribute'")
        found: Any = import_module(match.group("module"))
        for attribute in filter(None, (match.group("attr") or "").split(".")):
            found = getattr(found, attribute)
        return found


def _normalize(name: str) -> str:
    """PEP 503 with underscores (importlib.metadata.Prepared.normalize)."""
    return re.sub(r"[-_.]+", "-", name).lower().replace("-", "_")


def _metadata_dirs(paths: Iterable[str]) -> Iterable[tuple[str, str]]:
    """(normalised distribution name, its metadata folder), in sys.path order."""
    for root in paths:
        try:
            children = os.listdir(root or ".")  # unsorted, as importlib.metadata reads it
        except OSError:  # a zip file, a path hook, a folder that went away
            continue
        for child in children:
            stem, ext = os.path.splitext(child)
            if ext in _METADATA_DIRS:
                yield _normalize(stem.partition("-")[0]), os.path.join(root, child)


def _parse(text: str, group: str) -> list[tuple[str, str]]:
    """The ``name = value`` lines of ``[group]`` in an ``entry_points.txt``."""
    section, found = None, []
    for line in text.splitlines():
        line = line.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("[") and line.endswith("]"):
            section = line[1:-1].strip()
        elif section == group and "=" in line:
            name, _, value = line.partition("=")
            found.append((name.strip(), value.strip()))
    return found


def find_plugins(group: str, paths: Iterable[str] | None = None) -> list[Plugin]:
    """The entry points of ``group`` of every distribution on ``paths`` (default ``sys.path``)."""
    seen: set[str] = set()
    plugins: list[Plugin] = []
    for name, folder in _metadata_dirs(sys.path if paths is None else paths):
        if name in seen:
            continue
        seen.add(name)
        try:
            with open(os.path.join(folder, "entry_points.txt"), encoding="utf-8") as f:
                text = f.read()
        except (OSError, UnicodeDecodeError):
            continue
        plugins += [Plugin(n, v, group) for n, v in _parse(text, group)]
    return plugins
