"""fleet.manager.reconciler: a batch of joins is one run; the vehicle that makes the plant invalid
is refused alone (file to refused/ with its reason), the others join. The real validation step
(apply_step.check: load, SHACL, reason, derive; no agent) on the shipped AGV fleet plant."""

from __future__ import annotations

from pathlib import Path

from fleet.discovery.inbox import Interface, VehicleKey
from fleet.discovery.records import DataDir, VehicleRecord
from fleet.manager import apply_step
from fleet.manager.plant import binding_and_address
from fleet.manager.reconciler import Reconciler
from fleet.manager.service import describe, render_record
from tests.unit.fleet import discovery_data as d

PLANT = Path(__file__).resolve().parents[3] / "ontology" / "examples" / "agv-fleet.ttl"


def join(data: DataDir, manufacturer: str, serial: str) -> str:
    binding, _ = binding_and_address([PLANT])
    desc = describe(VehicleKey(Interface.VDA5050, manufacturer, serial), d.factsheet(manufacturer, serial))
    record = VehicleRecord("vda5050", manufacturer, serial, manufacturer, desc, binding)
    data.save(record)
    return record.stem


def reconciler(tmp_path: Path, runs: list[list[Path]]) -> tuple[Reconciler, DataDir]:
    data = DataDir(tmp_path, render_record)

    def step(files: list[Path]) -> apply_step.StepResult:
        runs.append(files)
        return apply_step.check(files)
    return Reconciler([PLANT], data, step, apply_step.check), data


def test_a_batch_of_good_vehicles_is_one_run(tmp_path: Path) -> None:
    runs: list[list[Path]] = []
    rec, data = reconciler(tmp_path, runs)
    stems = {join(data, "acme", f"a-{i}") for i in range(3)}
    report = rec.run(stems)
    assert report.step.valid and report.refused == () and set(report.joined) == stems
    assert len(runs) == 1 and runs[0][0] == PLANT and len(runs[0]) == 2  # the plant, the vehicles' bundle
    assert runs[0][1].read_text(encoding="utf-8").count("# --- ") == 3


def test_the_vehicle_that_makes_the_plant_invalid_is_refused_alone(tmp_path: Path) -> None:
    runs: list[list[Path]] = []
    rec, data = reconciler(tmp_path, runs)
    good = join(data, "acme", "a-1")
    clash = join(data, "other", "sim-0001")  # the plant already has a vehicle with this serial
    report = rec.run({good, clash})
    assert [stem for stem, _ in report.refused] == [clash]
    reason = report.refused[0][1]
    assert reason.startswith("the plant would be invalid with this vehicle:") and "agv-sim-0001" in reason
    assert report.step.valid and report.joined == (good,)
    assert [p.name for p in data.turtle_files()] == ["acme--a-1.ttl"]
    assert (tmp_path / "refused" / "other--sim-0001.ttl").exists()
    assert "agv-sim-0001" in (tmp_path / "refused" / "other--sim-0001.reason.txt").read_text()
    assert [r.stem for r in data.records()] == [good]
    assert len(runs) == 2  # the batch, then the batch without the refused vehicle


def test_a_plant_invalid_without_the_new_vehicles_refuses_none_of_them(tmp_path: Path) -> None:
    broken = tmp_path / "broken.ttl"
    broken.write_text(PLANT.read_text().replace('pk:name "fleet-mqtt" ;', ""), encoding="utf-8")
    data = DataDir(tmp_path / "data", render_record)
    rec = Reconciler([broken], data, apply_step.check, apply_step.check)
    stem = join(data, "acme", "a-1")
    report = rec.run({stem})
    assert not report.step.valid and report.refused == () and report.joined == ()
    assert [p.name for p in data.turtle_files()] == ["acme--a-1.ttl"]


def test_vehicles_that_joined_before_go_to_the_pipeline_in_one_bundle(tmp_path: Path) -> None:
    """The vehicles reach the pipeline as one file (the pipeline over hundreds of files is several
    times slower); only an invalid plant is checked with the new ones apart (the other tests)."""
    runs: list[list[Path]] = []
    rec, data = reconciler(tmp_path, runs)
    old = {join(data, "acme", f"o-{i}") for i in range(3)}
    assert rec.run(old).step.valid
    new = join(data, "acme", "n-1")
    report = rec.run({new})
    assert report.step.valid and report.joined == (new,)
    files = runs[-1]
    bundle = tmp_path / "cache" / "vehicles.ttl"
    assert files == [PLANT, bundle]
    text = bundle.read_text(encoding="utf-8")
    assert all(f"# --- {stem}.ttl" in text for stem in (*old, new))
    # a vehicle's file rewritten (a person's rename does that): the bundle follows
    before = bundle.stat().st_mtime_ns
    path = data.discovered / f"{sorted(old)[0]}.ttl"
    path.write_text(path.read_text(encoding="utf-8") + "# rewritten\n", encoding="utf-8")
    assert rec.run(set()).step.valid
    assert "# rewritten" in bundle.read_text(encoding="utf-8") and bundle.stat().st_mtime_ns != before
    # nothing changed: the bundle is not written again
    before = bundle.stat().st_mtime_ns
    rec.run(set())
    assert bundle.stat().st_mtime_ns == before
