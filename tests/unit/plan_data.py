"""Read the planning cases' JSON (``to_dict`` output) back into engine.model values.

A small typed decoder for tests: each dataclass field is rebuilt from its annotation
(dataclasses, tuples of them, enums, optionals).
"""

from __future__ import annotations

import enum
import json
import types
import typing
from dataclasses import fields, is_dataclass
from pathlib import Path
from typing import Any, TypeVar

from engine import model
from engine.model import DesiredState, ObservedState

T = TypeVar("T")
CASES = Path(__file__).resolve().parents[1] / "cases" / "plan"


def decode(cls: Any, data: Any) -> Any:
    """``data`` (JSON) as an instance of the type ``cls``."""
    origin = typing.get_origin(cls)
    if origin in (typing.Union, types.UnionType):
        if data is None:
            return None
        inner = [a for a in typing.get_args(cls) if a is not type(None)]
        return decode(inner[0], data)
    if origin is tuple:
        item = typing.get_args(cls)[0]
        return tuple(decode(item, d) for d in data)
    if isinstance(cls, type) and issubclass(cls, enum.Enum):
        return cls(data)
    if is_dataclass(cls):
        hints = typing.get_type_hints(cls, vars(model))
        unknown = set(data) - {f.name for f in fields(cls)}
        assert not unknown, f"{cls.__name__}: unknown fields {unknown}"
        return cls(**{name: decode(hints[name], value) for name, value in data.items()})
    return data


def load_case(name: str) -> tuple[DesiredState, ObservedState, dict[str, Any]]:
    folder = CASES / name
    desired = decode(DesiredState, json.loads((folder / "desired.json").read_text()))
    observed = decode(ObservedState, json.loads((folder / "observed.json").read_text()))
    expected = json.loads((folder / "expected_plan.json").read_text())
    return desired, observed, expected


def case_names() -> list[str]:
    return sorted(p.name for p in CASES.iterdir() if (p / "expected_plan.json").is_file())
