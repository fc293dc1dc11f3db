"""The notebooks in notebooks/ run top to bottom in a real kernel and show what they promise.

Each notebook is executed with nbclient in an IPython kernel of this venv (ipykernel's ``python3``
kernel runs ``sys.executable``), with notebooks/ as its working folder; a cell error fails the test.
The executed copy is written under ``tmp_path`` only (the committed notebooks stay without
outputs). The kernel's TMPDIR is ``tmp_path``, so every agent and broker a notebook starts names a
path under it: after the kernel stopped, no process may name ``tmp_path`` any more.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
from pathlib import Path

import nbformat
import pytest
import rdflib
from nbclient import NotebookClient
from nbclient.exceptions import CellExecutionError
from traitlets.config import Config

from engine.errors import WaitTimeoutError
from engine.demo.local_plant import processes_under
from engine.process import wait_until
from kg.namespaces import PK
from kg.resources import examples_dir, project_root

NOTEBOOKS = project_root() / "notebooks"
ANSI = re.compile(r"\x1b\[[0-9;]*m")


def execute(name: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
            edit: object = None) -> nbformat.NotebookNode:
    """Run notebook ``name`` (after ``edit(nb)`` if given); the executed copy goes to tmp_path."""
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    assert all(not c.get("outputs") for c in nb.cells if c.cell_type == "code"), \
        f"{name} is committed with outputs: clear them"
    if callable(edit):
        edit(nb)
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    # Shutting the kernel down lets the notebook's clean-up (stopping agents) finish before a kill.
    config = Config({"KernelManager": {"shutdown_wait_time": 60.0}})
    client = NotebookClient(nb, timeout=240, kernel_name="python3", config=config,
                            resources={"metadata": {"path": str(NOTEBOOKS)}})
    try:
        client.execute()
    finally:
        nbformat.write(nb, tmp_path / name)
        left = processes_under(tmp_path)
        terminate(left, tmp_path)
        assert not left, "the notebook left processes behind:\n" + "\n".join(left)
    return nb


def terminate(lines: list[str], folder: Path) -> None:
    """End processes a failed notebook left (``pid: argv`` lines), so a failure leaks nothing."""
    pids = [int(line.split(":", 1)[0]) for line in lines]
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGTERM)
    with contextlib.suppress(WaitTimeoutError):
        wait_until(lambda: not processes_under(folder), 20, 0.1, what="leftover processes to stop")
    for pid in pids:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)


def cell(nb: nbformat.NotebookNode, cell_id: str) -> nbformat.NotebookNode:
    return next(c for c in nb.cells if c.get("id") == cell_id)


def text(nb: nbformat.NotebookNode, cell_id: str) -> str:
    """Everything a cell printed or displayed as text, colours removed."""
    parts = []
    for out in cell(nb, cell_id).outputs:
        if out.output_type == "stream":
            parts.append(out.text)
        elif "data" in out:
            parts.append(out.data.get("text/plain", ""))
    return ANSI.sub("", "".join(parts))


def html(nb: nbformat.NotebookNode, cell_id: str) -> str:
    return "".join(o.data.get("text/html", "") for o in cell(nb, cell_id).outputs if "data" in o)


def table_rows(output: str) -> list[list[str]]:
    """The rows of a kg.table.Table's text form: the lines between its rule and its row count."""
    lines = output.strip().splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("─")) + 1
    return [line.split() for line in lines[start:] if line.strip() and not line.startswith("(")]


# ---------------------------------------------------------------------- 01: explore with SPARQL

def test_explore_notebook_shows_the_plant(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    nb = execute("01-explore-plant.ipynb", tmp_path, monkeypatch)
    plant = rdflib.Graph().parse(str(examples_dir() / "multi-machine.ttl"), format="turtle")
    brokers = {str(plant.value(b, PK.id)): (str(plant.value(b, PK.ip)), str(plant.value(b, PK.brokerType)))
               for b in plant.subjects(PK.brokerType, None)}

    assert "valid: True" in text(nb, "load-validate")
    shown = {row[1]: (row[0], row[2]) for row in table_rows(text(nb, "brokers-per-machine"))}
    assert shown == brokers
    assert all(f"<td>{broker}</td>" in html(nb, "brokers-per-machine") for broker in brokers)

    robots = text(nb, "robots")
    assert "Robot A1" in robots and "Robot B1" in robots and "PLC A" not in robots

    topics = {str(plant.value(b, PK.id)): len(set(plant.objects(b, PK.hasTopic)))
              for b in plant.subjects(PK.brokerType, None)}
    assert {row[0]: int(row[2]) for row in table_rows(text(nb, "topics-per-broker"))} == topics

    bridges = {(row[0], row[1]) for row in table_rows(text(nb, "bridges"))}
    assert bridges == {(str(plant.value(a, PK.id)), str(plant.value(c, PK.id)))
                       for a, c in plant.subject_objects(PK.bridgesTo)}

    assert any("image/png" in o.get("data", {}) for o in cell(nb, "plot").outputs)
    senders = {str(plant.value(b, PK.id)): len(set(plant.subjects(PK.sendsTo, b)))
               for b in plant.subjects(PK.brokerType, None)}
    plotted = {row[0]: (int(row[1]), int(row[2])) for row in table_rows(text(nb, "plot"))}
    assert plotted == {b: (senders[b], topics[b]) for b in brokers}
    assert re.search(r"^bridge\.mosquitto\.kafka\s+asserted$", text(nb, "robot-cell-desired"), re.M)
    assert (tmp_path / "01-explore-plant.ipynb").is_file()


# ------------------------------------------------------------- 02: plan and apply, for real

@pytest.mark.integration
def test_plan_and_apply_notebook_runs_the_plant_and_cleans_up(tmp_path: Path,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    nb = execute("02-plan-and-apply.ipynb", tmp_path, monkeypatch)
    ports = {k: int(v) for k, v in re.findall(r"'([\w-]+)': (\d+)", text(nb, "start-agents"))}
    assert set(ports) == {"mqtt-a", "mqtt-b"}

    assert "Plan: 5 to create, 0 to update, 0 to replace, 0 to destroy." in text(nb, "plan-first")
    assert "Apply complete: 5 changed, 0 failed" in text(nb, "apply-first")
    before = {row[0]: row for row in table_rows(text(nb, "status-before"))}
    assert {b: (r[2], r[3]) for b, r in before.items()} == {
        "mqtt-a": (f"127.0.0.2:{ports['mqtt-a']}", "running"),
        "mqtt-b": (f"127.0.0.3:{ports['mqtt-b']}", "running")}

    running = text(nb, "processes")
    assert running.count("mosquitto -c ") == 2 and running.count(" agent --listen ") == 2

    new_port = int(re.search(r"mqtt-a moves to port (\d+)", text(nb, "change-port")).group(1))  # type: ignore[union-attr]
    assert "broker.mqtt-a must be replaced" in text(nb, "change-port")
    # mqtt-b has no change (plan may still warn that it is open: that line is not a change)
    assert not re.search(r"^\s*[-+~]+\s+broker\.mqtt-b\b|broker\.mqtt-b (will|must) be", text(nb, "change-port"), re.M)
    assert "0 to update, 1 to replace, 0 to destroy." in text(nb, "change-port")
    assert "Apply complete: 1 changed, 0 failed" in text(nb, "apply-change")
    after = {row[0]: row for row in table_rows(text(nb, "status-after"))}
    assert after["mqtt-a"][2:4] == [f"127.0.0.2:{new_port}", "running"]
    assert after["mqtt-a"][4] != before["mqtt-a"][4]          # a new process
    assert after["mqtt-b"][4] == before["mqtt-b"][4]          # untouched
    assert "No changes." in text(nb, "plan-empty")

    assert "Destroy complete: 5 changed, 0 failed" in text(nb, "destroy")
    assert "processes left: none" in text(nb, "close")


@pytest.mark.integration
def test_a_failing_cell_leaves_no_broker_behind(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A cell fails right after apply: execution stops, the kernel is shut down, and the session's
    exit hook deletes the brokers and stops the agents (``execute`` checks no process is left)."""
    def break_after_apply(nb: nbformat.NotebookNode) -> None:
        at = next(i for i, c in enumerate(nb.cells) if c.get("id") == "apply-first")
        nb.cells.insert(at + 1, nbformat.v4.new_code_cell('raise RuntimeError("a cell failed")'))

    with pytest.raises(CellExecutionError, match="a cell failed"):
        execute("02-plan-and-apply.ipynb", tmp_path, monkeypatch, edit=break_after_apply)
    ran = nbformat.read(tmp_path / "02-plan-and-apply.ipynb", as_version=4)
    assert "Apply complete: 5 changed" in text(ran, "apply-first")   # brokers really ran
