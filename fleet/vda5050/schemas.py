"""JSON-schema validation of received VDA 5050 messages, with the official 2.1 schemas.

The schemas are the VDA 5050 project's own (draft 2020-12), as bundled by PyPI ``vda5050-sdk``
(``vda5050/validation/schemas/*.json``). They are read from that installed package at run time and
not copied into this repository: the sdk is MIT-licensed, but its README says the schema files
"belong to the VDA 5050 community", so we leave them where their distributor put them.
``PLANTKG_VDA5050_SCHEMA_DIR`` points at another folder with the same file names (for example a
checkout of github.com/VDA5050/VDA5050 ``json_schemas``).

A refused message raises :class:`SchemaError` with the path inside the message (``nodes/0/
sequenceId``) and the reason; the first error jsonschema ranks best is reported, the others are
in ``all_problems``.
"""

from __future__ import annotations

import importlib.util
import json
import os
from functools import lru_cache
from pathlib import Path
from typing import Any

import jsonschema
from jsonschema import Draft202012Validator
from jsonschema.exceptions import best_match

from fleet.vda5050.errors import SchemaError, Vda5050Error
from fleet.vda5050.topics import Subtopic

SCHEMA_DIR_ENV = "PLANTKG_VDA5050_SCHEMA_DIR"
MAX_MESSAGE_BYTES = 1_000_000  # far above any real order; a 10 MB "factsheet" is refused unread

FILE_NAMES: dict[Subtopic, str] = {
    Subtopic.ORDER: "order.json",
    Subtopic.INSTANT_ACTIONS: "instantActions.json",
    Subtopic.STATE: "state.json",
    Subtopic.VISUALIZATION: "visualization.json",
    Subtopic.CONNECTION: "connection.json",
    Subtopic.FACTSHEET: "factsheet.json",
}


def schema_dir() -> Path:
    """Where the official schemas are: the override folder, else the installed vda5050-sdk."""
    override = os.environ.get(SCHEMA_DIR_ENV)
    if override:
        return Path(override)
    spec = importlib.util.find_spec("vda5050")
    if spec is None or not spec.submodule_search_locations:
        raise Vda5050Error(
            "the VDA 5050 JSON schemas are not available: package vda5050-sdk is not installed",
            hint=f"pip install 'vda5050-sdk==0.2.0', or set {SCHEMA_DIR_ENV} to a folder with order.json, state.json, ...",
        )
    return Path(next(iter(spec.submodule_search_locations))) / "validation" / "schemas"


@lru_cache(maxsize=None)
def _validator(kind: Subtopic, folder: str) -> Draft202012Validator:
    path = Path(folder) / FILE_NAMES[kind]
    try:
        schema = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise Vda5050Error(f"cannot read the VDA 5050 schema {path}: {exc}",
                           hint=f"reinstall vda5050-sdk or fix {SCHEMA_DIR_ENV}") from exc
    Draft202012Validator.check_schema(schema)
    return Draft202012Validator(schema, format_checker=Draft202012Validator.FORMAT_CHECKER)


def validator(kind: Subtopic | str) -> Draft202012Validator:
    return _validator(Subtopic(kind), str(schema_dir()))


def _path(error: jsonschema.ValidationError) -> str:
    return "/".join(str(part) for part in error.absolute_path)


def problems(kind: Subtopic | str, message: Any) -> list[tuple[str, str]]:
    """Every (path, reason) the schema finds in ``message``; empty when it is valid."""
    found = validator(kind).iter_errors(message)
    return sorted((_path(e), e.message) for e in found)


def check(kind: Subtopic | str, message: Any) -> dict[str, Any]:
    """Return ``message`` if the schema of ``kind`` accepts it, else raise :class:`SchemaError`."""
    errors = list(validator(kind).iter_errors(message))
    if errors:
        best = best_match(errors)
        error = SchemaError(Subtopic(kind).value, _path(best), best.message)
        error.all_problems = sorted((_path(e), e.message) for e in errors)
        raise error
    return message


def parse(kind: Subtopic | str, payload: bytes | str) -> dict[str, Any]:
    """Decode a received payload (UTF-8 JSON object) and check it against the schema of ``kind``."""
    name = Subtopic(kind).value
    size = len(payload)
    if size > MAX_MESSAGE_BYTES:
        raise SchemaError(name, "", f"message is {size} bytes, more than the {MAX_MESSAGE_BYTES} accepted")
    try:
        text = payload.decode("utf-8") if isinstance(payload, bytes) else payload
        message = json.loads(text)
    except (UnicodeDecodeError, ValueError) as exc:
        raise SchemaError(name, "", f"not UTF-8 JSON: {exc}") from None
    if not isinstance(message, dict):
        raise SchemaError(name, "", f"a message is a JSON object, got {type(message).__name__}")
    return check(kind, message)
