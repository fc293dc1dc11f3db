"""A batch of joins -> one reconcile; a vehicle that makes the plant invalid is refused alone.

:meth:`Reconciler.run` takes the stems (``manufacturer--serial``) of the vehicles written since
the last run. The plant is its files plus the discovered vehicles, bundled into one file (the
pipeline over hundreds of small files is several times slower than over one). If that is
invalid, it is checked again with the new vehicles each in its own file, so that a violation
names its vehicle, and:

1. the plant without the new vehicles is checked (validation only, no agent asked): if that is
   invalid too, a person broke it, and nothing is refused or applied (the report says so);
2. violations whose focus node lives in a new vehicle's file name that vehicle, if the plant
   without those vehicles is valid;
3. otherwise each new vehicle is checked alone with the plant, and those invalid alone are refused;
4. a refused vehicle's file moves to ``refused/`` with ``.reason.txt`` (the violations), its
   record is dropped, a log line names it and the reason; the rest is reconciled.

The steps are injected (``apply_step`` by default).
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from fleet.discovery import files
from fleet.discovery.records import DataDir
from fleet.manager.apply_step import StepResult, Violation

log = logging.getLogger("fleet.manager")

Step = Callable[[list[Path]], StepResult]


@dataclass(frozen=True)
class ReconcileReport:
    step: StepResult
    refused: tuple[tuple[str, str], ...] = ()  # (stem, reason)
    joined: tuple[str, ...] = ()               # stems reconciled in this run


def _reason(violations: Iterable[Violation]) -> str:
    lines = list(dict.fromkeys(f"{v.focus}: {v.message}" if v.focus else v.message for v in violations))
    more = f" | ... {len(lines) - 10} more" if len(lines) > 10 else ""
    return "the plant would be invalid with this vehicle: " + " | ".join(lines[:10]) + more


def bundle(paths: list[Path], folder: Path) -> list[Path]:
    """``paths`` as one Turtle file in ``folder`` (rewritten atomically when their text changed), or
    nothing when there are none. Turtle documents concatenate into one document: the generated
    vehicle files name every node, so no blank-node label can clash."""
    if not paths:
        return []
    text = "\n".join(f"# --- {p.name}\n" + p.read_text(encoding="utf-8") for p in paths)
    digest = hashlib.sha256(text.encode("utf-8")).hexdigest()
    target, stamp = folder / "vehicles.ttl", folder / "vehicles.sha256"
    try:
        if target.is_file() and stamp.read_text(encoding="utf-8") == digest:
            return [target]
    except OSError:
        pass
    folder.mkdir(parents=True, exist_ok=True)
    files.atomic_write(target, text)
    files.atomic_write(stamp, digest)
    return [target]


class Reconciler:
    def __init__(self, plant_files: list[Path], data: DataDir, apply_step: Step, check_step: Step) -> None:
        self.plant_files = [Path(f) for f in plant_files]
        self.data = data
        self.apply_step = apply_step
        self.check_step = check_step

    def files(self, without: Iterable[Path] = (), apart: Iterable[Path] = ()) -> list[Path]:
        """The plant's files and the vehicles' (but ``without``): the vehicles in ``apart`` (the
        new ones, whose violations must name their own file) each in its own file, all the others
        in one bundle — the pipeline is ~6x slower over 200 files than over one (Oxigraph's union
        of many named graphs)."""
        skip = {p.resolve() for p in without}
        alone = {p.resolve() for p in apart}
        vehicles = [p for p in self.data.turtle_files() if p.resolve() not in skip]
        kept_apart = [p for p in vehicles if p.resolve() in alone]
        rest = [p for p in vehicles if p.resolve() not in alone]
        return self.plant_files + bundle(rest, self.data.root / "cache") + kept_apart

    def run(self, new: set[str]) -> ReconcileReport:
        # Everything in one bundle first (the common case: the batch is valid and applied). Only
        # an invalid plant is checked again with the new vehicles apart, to name the culprits.
        result = self.apply_step(self.files())
        refused: list[tuple[str, str]] = []
        if not result.valid:
            apart = [self.data.discovered / f"{s}.ttl" for s in new]
            named = self.check_step(self.files(apart=apart)) if new else result
            refused = self._culprits(new, named if not named.valid else result)
            if refused:
                for stem, reason in refused:
                    path = self.data.discovered / f"{stem}.ttl"
                    with self.data.lock():
                        self.data.refuse(stem, reason, turtle=path)
                    log.warning("refused vehicle %s: %s", stem, reason)
                result = self.apply_step(self.files())
        stems = tuple(sorted(new - {s for s, _ in refused}))
        return ReconcileReport(result, tuple(refused), stems if result.valid else ())

    def _culprits(self, new: set[str], result: StepResult) -> list[tuple[str, str]]:
        new_paths = {s: self.data.discovered / f"{s}.ttl" for s in new}
        apart = list(new_paths.values())
        base = self.check_step(self.files(without=apart)) if new else result
        if not base.valid:
            log.error("the plant is invalid without the new vehicles; nothing refused, nothing applied: %s",
                      _reason(base.violations))
            return []
        by_stem: dict[str, list[Violation]] = {}
        owner = {p.resolve(): s for s, p in new_paths.items()}
        for v in result.violations:
            stem = owner.get(Path(v.file).resolve()) if v.file is not None else None
            if stem is not None:
                by_stem.setdefault(stem, []).append(v)
        found = {stem: _reason(vs) for stem, vs in by_stem.items()}
        if found and self.check_step(self.files(without=[new_paths[s] for s in found], apart=apart)).valid:
            return sorted(found.items())
        found = {}
        for stem, path in sorted(new_paths.items()):  # each new vehicle alone with the plant
            single = self.check_step(self.files(without=[p for p in new_paths.values() if p != path], apart=[path]))
            if not single.valid:
                found[stem] = _reason(single.violations)
        return sorted(found.items())
