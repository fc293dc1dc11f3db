"""The task planner against a context broker with ``pk:tls true`` (issue 13), end to end.

The plant of tests/integration/cb_tls.py, applied through a real agent: its context broker speaks
HTTPS only, with a plant-CA certificate. ``python -m fleet.planner --start`` (no vehicles, the
manager away: a started job's tasks are still created and published) with ``--ngsi-url https://...
--ngsi-ca-file <the plant CA's ca.pem>`` writes its Task entities there: FiLiP, trusting the plant
CA only, reads them back. The same planner without the CA file (the system's store) exits 2 at
once, saying its certificate is not trusted and which option to give, without a traceback and
before it writes its data directory.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from engine import netutil, process
from engine.security import ca
from tests.integration.cb_tls import HOST, Plant, tls_plant

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
JOBS = ROOT / "fleet" / "examples" / "jobs.tl"


@pytest.fixture(scope="module")
def plant(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Plant]:
    with tls_plant(tmp_path_factory.mktemp("planner-tls")) as applied:
        yield applied


def spawn_planner(plant: Plant, tmp_path: Path, name: str, *trust: str) -> process.Child:
    """The planner on ``plant``'s context broker (its agent's token), a job started at once, the
    fleet manager a port nobody answers on."""
    (tmp_path / "manager.token").write_text("nobody\n", encoding="utf-8")
    return process.spawn(
        [sys.executable, "-m", "fleet.planner", "--plant", plant.plant, "--lotlan", JOBS, "--map", "default",
         "--data-dir", tmp_path / name, "--manager-url", f"http://127.0.0.1:{netutil.free_port()}",
         "--manager-token-file", tmp_path / "manager.token", "--start",
         "--ngsi-url", plant.url, "--ngsi-token-file", plant.agent_token_file, *trust],
        log_dir=tmp_path / "logs", name=name, cwd=ROOT)


def test_the_planner_trusting_the_plant_ca_publishes_its_tasks(plant: Plant, tmp_path: Path) -> None:
    planner = spawn_planner(plant, tmp_path, "planner", "--ngsi-ca-file", str(ca.ca_cert_file()))
    reader = plant.filip(plant.fleet.agents[HOST].token)
    try:
        tasks = process.wait_until(lambda: reader.get_entity_list(entity_types=["Task"]), 60.0, 0.2,
                                   what="the planner's Task entities on the TLS context broker", child=planner)
        assert all(t.id.startswith("urn:ngsi-ld:Task:j1-") for t in tasks), tasks
        assert {t.get_attribute("job").value for t in tasks} == {"j1"}
        assert "does not answer" not in planner.log_tail(20000), planner.log_tail()
    finally:
        assert process.stop(planner) == 0, planner.log_tail()


def test_the_planner_without_the_ca_file_exits_2_naming_the_certificate(plant: Plant, tmp_path: Path) -> None:
    planner = spawn_planner(plant, tmp_path, "untrusting")  # https:// with the system's store
    exited = process.wait_exit(planner.popen, 60.0)
    code = process.stop(planner)  # reaps it (and stops one that kept running)
    log = planner.log_tail(20000)
    assert exited and code == 2, log
    assert f"{plant.url} shows a certificate that is not trusted" in log and "--ngsi-ca-file" in log, log
    assert "Traceback" not in log and not (tmp_path / "untrusting").exists(), log
