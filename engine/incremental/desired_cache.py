"""Remember the desired state of a valid plant, so re-planning an unchanged plant is cheap.

Load, validate, reason and derive depend only on the files (plant, ontology, shapes) and on the
engines chosen, and take about 2 s for a 10k-resource plant; observe and plan must run every time
because the agents' side changes. The cache keys the desired state (and the validation report)
by a SHA-256 of everything those stages read — plantkg's version, the engines, every ontology and
shapes file, every plant file's path and bytes — so any edit misses the cache. Only valid plants
are stored: an invalid plant is always validated again, so its report is always current.

Entries are JSON files under ``$PLANTKG_CACHE_DIR`` (default ``$XDG_CACHE_HOME/plantkg`` or
``~/.cache/plantkg``); deleting the folder is always safe.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
from dataclasses import asdict
from importlib import metadata
from pathlib import Path
from typing import Iterable

from engine.model import (
    BridgeDirection,
    BridgeEnd,
    BridgeMechanism,
    BridgeRoute,
    BridgeSpec,
    BrokerSpec,
    KafkaNode,
    KafkaVoter,
    BrokerUser,
    DesiredState,
    TopicSpec,
    to_dict,
)
from kg import resources, shape_plugins
from kg.validate import ValidationReport, ValidationResult
from engine.whole_file import write_whole

FORMAT = 6  # 2: the desired state holds its owner; 3: closed Mosquittos, bridge principals, tls;
#            4: a context broker's closed_kafkas; 5: closed Kafka bridge ends; 6: its tls_kafkas


def default_dir() -> Path:
    if env := os.environ.get("PLANTKG_CACHE_DIR"):
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "plantkg"


@functools.cache
def _version() -> str:
    """plantkg's installed version (read once: parsing the package metadata took ~20 ms, on every
    key)."""
    try:
        return metadata.version("plantkg")
    except metadata.PackageNotFoundError:  # running from a checkout without install
        return "dev"


class DesiredCache:
    """A folder of cached desired states, one JSON file per key."""

    def __init__(self, directory: Path | None = None) -> None:
        self.directory = directory or default_dir()

    def key(self, files: Iterable[Path | str], *, reason_engine: str, validate_engine: str) -> str:
        """The hash of everything load/validate/reason/derive read for ``files``."""
        h = hashlib.sha256(f"plantkg {_version()} cache {FORMAT} {reason_engine} {validate_engine}\n".encode())
        inputs = [*resources.tbox_files(), *resources.shapes_files(), *shape_plugins.plugin_shapes_files()]
        h.update(" ".join(shape_plugins.registered_broker_types()).encode() + b"\0")  # the shapes' brokerType values
        for path in [*sorted(inputs), *(Path(f) for f in files)]:
            h.update(str(Path(path).resolve()).encode() + b"\0")
            h.update(Path(path).read_bytes())
            h.update(b"\0")
        return h.hexdigest()

    def get(self, key: str) -> tuple[DesiredState, ValidationReport] | None:
        """The cached desired state and report, or None (missing or unreadable: recompute)."""
        try:
            data = json.loads((self.directory / f"{key}.json").read_text(encoding="utf-8"))
            return desired_from_dict(data["desired"]), report_from_dict(data["report"])
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def put(self, key: str, desired: DesiredState, report: ValidationReport) -> None:
        """Store a valid plant's desired state (best effort: a read-only cache is no error)."""
        if not report.conforms:
            return
        body = json.dumps({"desired": to_dict(desired), "report": {
            "conforms": report.conforms, "engine": report.engine, "files": list(report.files),
            "shapes": list(report.shapes), "results": [asdict(r) for r in report.results]}})
        try:
            self.directory.mkdir(parents=True, exist_ok=True)
            write_whole(self.directory / f"{key}.json", body)
        except OSError:
            return


def desired_from_dict(data: dict) -> DesiredState:
    """The inverse of ``to_dict(desired)``."""
    return DesiredState(
        brokers=tuple(BrokerSpec(**{**b, "users": tuple(BrokerUser(**{**u, "write": tuple(u["write"]),
                                                                            "read": tuple(u["read"])})
                                                         for u in b.get("users", ())),
                                    "kafka": _kafka_node(b.get("kafka")),
                                    "closed_kafkas": tuple(b.get("closed_kafkas", ())),
                                    "tls_kafkas": tuple(b.get("tls_kafkas", ()))})
                      for b in data["brokers"]),
        topics=tuple(TopicSpec(**t) for t in data["topics"]),
        bridges=tuple(bridge_from_dict(b) for b in data["bridges"]),
        owner=data.get("owner"),
    )


def _kafka_node(data: dict | None) -> KafkaNode | None:
    if data is None:
        return None
    return KafkaNode(**{**data, "roles": tuple(data["roles"]), "bootstrap": tuple(data["bootstrap"]),
                        "voters": tuple(KafkaVoter(**v) for v in data["voters"])})


def _end(data: dict) -> BridgeEnd:
    return BridgeEnd(**{**data, "bootstrap": tuple(data.get("bootstrap", ()))})


def bridge_from_dict(data: dict) -> BridgeSpec:
    """The inverse of ``to_dict(bridge)`` (trusted data: the cache's own, or an agent's answer
    already checked by engine.agent.wire)."""
    return BridgeSpec(
        local=_end(data["local"]),
        remote=_end(data["remote"]),
        mechanism=BridgeMechanism(data["mechanism"]),
        routes=tuple(BridgeRoute(**{**r, "direction": BridgeDirection(r["direction"])})
                     for r in data["routes"]),
        asserted=data["asserted"],
    )


def report_from_dict(data: dict) -> ValidationReport:
    return ValidationReport(
        conforms=data["conforms"], engine=data["engine"], files=tuple(data["files"]),
        shapes=tuple(data["shapes"]), results=tuple(ValidationResult(**r) for r in data["results"]),
    )
