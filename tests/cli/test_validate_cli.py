"""``plantkg validate``: exit codes, what a person reads, what a program reads."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import click

from tests.cli.conftest import EXAMPLES, ROOT


def test_valid_example(plantkg) -> None:
    run = plantkg("validate", EXAMPLES / "robot-cell.ttl")
    assert run.code == 0, run.out
    assert click.unstyle(run.out).startswith(f"valid: {EXAMPLES / 'robot-cell.ttl'}")


def test_several_files_validate_as_one_plant(plantkg) -> None:
    examples = sorted(EXAMPLES.glob("*.ttl"))
    run = plantkg("validate", "--format", "json", *examples)
    data = json.loads(run.out)
    # The examples reuse ids (e.g. the resource type "industrial-robot") on purpose-free
    # grounds: as one plant those ids collide, and validation must say so.
    assert len(examples) >= 2 and len(data["files"]) == len(examples)
    assert data["engine"] == "oxigraph"
    assert run.code == (0 if data["conforms"] else 1)


def test_violation_names_file_node_property_value(plantkg, write) -> None:
    text = (EXAMPLES / "robot-cell.ttl").read_text()
    assert "pk:port 1883" in text
    path = write("cell.ttl", text.replace("pk:port 1883", "pk:port 70000", 1))
    run = plantkg("validate", path)
    assert run.code == 1
    out = click.unstyle(run.out)
    assert out.startswith(f"invalid: {path}: 1 violation, 0 warnings")
    assert "rc:mosquitto  pk:port = 70000" in out
    assert f"· {path}" in out
    assert "65535" in out  # the message says what is allowed


def test_json_report(plantkg, write) -> None:
    text = (EXAMPLES / "robot-cell.ttl").read_text()
    path = write("cell.ttl", text.replace("pk:port 1883", "pk:port 70000", 1))
    run = plantkg("validate", "--format", "json", path)
    assert run.code == 1
    data = json.loads(run.out)
    assert data["conforms"] is False and data["violations"] == 1
    (result,) = data["results"]
    assert result["focus"] == "https://w3id.org/plantkg/examples/robot-cell#mosquitto"
    assert result["path"] == "https://w3id.org/plantkg/ontology#port"
    assert result["value"] == "70000"
    assert result["file"] == str(path)
    assert result["severity"] == "Violation"


def test_reference_engine_gives_same_report(plantkg, write) -> None:
    text = (EXAMPLES / "robot-cell.ttl").read_text()
    path = write("cell.ttl", text.replace("pk:port 1883", "pk:port 0", 1))
    fast = json.loads(plantkg("validate", "--format", "json", path).out)
    ref = json.loads(plantkg("validate", "--format", "json", "--engine", "pyshacl", path).out)
    assert ref["engine"] == "pyshacl"
    assert fast["results"] == ref["results"]


def test_console_script_in_a_pipe_is_plain_and_has_no_traceback(tmp_path: Path) -> None:
    exe = shutil.which("plantkg", path=str(Path(sys.executable).parent)) or "plantkg"
    bad = tmp_path / "bad.ttl"
    bad.write_text("@prefix pk: <https://w3id.org/plantkg/ontology#> .\npk:x pk:y \n")
    proc = subprocess.run([exe, "validate", str(bad)], capture_output=True, text=True, cwd=ROOT,
                          env={**os.environ, "NO_COLOR": "1"})
    assert proc.returncode == 2
    assert "Traceback" not in proc.stderr
    assert f"{bad}:3:" in proc.stderr
    assert "\x1b[" not in proc.stderr + proc.stdout
    ok = subprocess.run([exe, "validate", str(EXAMPLES / "robot-cell.ttl")], capture_output=True,
                        text=True, cwd=ROOT)
    assert ok.returncode == 0 and "\x1b[" not in ok.stdout
