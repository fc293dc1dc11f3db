"""Where the ontology and the shapes live.

plantkg is installed editable from its repository (``make setup``), so the TBox (``ontology/``) and
the shapes (``shapes/``) are read from the repository root, next to the packages. The environment
variable ``PLANTKG_HOME`` points elsewhere (a deployment that keeps the files in another place).
"""

from __future__ import annotations

import os
from pathlib import Path

from kg.errors import PlantKGError
from kg.shape_plugins import plugin_ontology_files


def project_root() -> Path:
    """The folder that holds ``ontology/`` and ``shapes/``."""
    env = os.environ.get("PLANTKG_HOME")
    root = Path(env) if env else Path(__file__).resolve().parent.parent
    if not (root / "ontology" / "plantkg.ttl").is_file():
        raise PlantKGError(
            f"{root} holds no ontology/plantkg.ttl",
            hint="set PLANTKG_HOME to a plantkg checkout, or reinstall with `make setup`",
        )
    return root


def ontology_file() -> Path:
    """The TBox in Turtle (``ontology/plantkg.ttl``)."""
    return project_root() / "ontology" / "plantkg.ttl"


def ontology_files() -> list[Path]:
    """Every TBox file (``ontology/*.ttl``, not the examples): the ontology first, then the others
    sorted (e.g. ``plantkg-rules.ttl``, the OWL definitions and SWRL rules the reasoner runs)."""
    main = ontology_file()
    others = sorted(p for p in main.parent.glob("*.ttl") if p != main)
    return [main, *others]


def tbox_files() -> list[Path]:
    """What the reasoner reads as the TBox: :func:`ontology_files`, then the ontology files of
    installed plugin packages (entry-point group ``plantkg.ontology``, :mod:`kg.shape_plugins`)."""
    return [*ontology_files(), *plugin_ontology_files()]


def shapes_files() -> list[Path]:
    """Every shapes file (``shapes/*.ttl``), sorted so results are reproducible."""
    files = sorted((project_root() / "shapes").glob("*.ttl"))
    if not files:
        raise PlantKGError(f"no shapes in {project_root() / 'shapes'}",
                           hint="restore shapes/*.ttl from the repository, or pass --shapes FILE")
    return files


def examples_dir() -> Path:
    """The example plants shipped with the ontology."""
    return project_root() / "ontology" / "examples"
