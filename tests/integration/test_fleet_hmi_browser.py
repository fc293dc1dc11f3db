"""The operators' screens in a real headless Chromium (Debian's, driven by Playwright), on the real
fleet: agents running Mosquitto and the context broker, the fleet manager, two simulated VDA 5050
AGVs joining by plug and play, the task planner and the HMI (``python -m fleet.hmi``), each its own
process (the rig of tests/integration/test_fleet_planner.py).

An operator logs in, starts a job at the loading station, watches a vehicle marker move on the
fleet page's map, presses **Loaded** when the station's page says "ready to load", goes to the
unloading station, presses **Unloaded** when it says "ready to unload", and sees the job FINISHED
(on the station's page and in the fleet page's order list, filtered); a second job is withdrawn
from the order list. The planner's journal shows
the two events in that order; the time of one poll of ``/api/fleet`` is printed (no timing asserts). Then the planner stops and the fleet page says it does not answer.
Screenshots go to the pytest tmp dir (``screenshots/``).
"""

from __future__ import annotations

import re
import shutil
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from engine import process
from tests.integration.test_fleet_planner import ROOT, Planner, Rig, spawn_sim, wait_ready, write_map
from tests.integration.test_fleet_planner import PARK
from tests.integration.test_fleet_planner import rig as rig  # noqa: F401 - the module's fixture

pytestmark = pytest.mark.integration

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
TOKEN = "hmi-browser-token-0123456789"
WAIT_S = 90.0

JOBS = """\
Location loadStation
    name = "load-1"
    type = "pallet"
End

Location unloadStation
    name = "unload-1"
    type = "pallet"
End

Event loaded
    name = "Loaded"
    type = "Boolean"
End

Event unloaded
    name = "Unloaded"
    type = "Boolean"
End

TransportOrderStep atLoad
    Location loadStation
    FinishedBy loaded == True
End

TransportOrderStep atUnload
    Location unloadStation
    FinishedBy unloaded == True
End

Task transport
    Transport
    From atLoad
    To atUnload
End
"""


def wait_js(page: Any, expression: str, what: str | None = None) -> Any:
    """Poll ``expression`` in the page until truthy (the HMI's Content-Security-Policy forbids the
    eval that Playwright's wait_for_function uses)."""
    return process.wait_until(lambda: page.evaluate(expression), WAIT_S, 0.2, what=what or expression)


def shot(page: Any, folder: Path, name: str) -> None:
    folder.mkdir(exist_ok=True)
    page.screenshot(path=str(folder / f"{name}.png"), full_page=True)
    assert (folder / f"{name}.png").stat().st_size > 10_000


@pytest.fixture
def browser() -> Iterator[Any]:
    if not Path(CHROMIUM).exists():
        pytest.fail(f"no Chromium at {CHROMIUM}: run `make setup` (it installs Debian's chromium)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        chromium = pw.chromium.launch(executable_path=CHROMIUM, headless=True)
        yield chromium
        chromium.close()


def spawn_hmi(rig: Rig, lotlan: Path, map_file: Path, planner_data: Path) -> tuple[process.Child, str]:  # noqa: F811
    token_file = rig.tmp / "hmi-token"
    token_file.write_text(TOKEN + "\n", encoding="utf-8")
    token_file.chmod(0o600)
    child = process.spawn([sys.executable, "-m", "fleet.hmi", "--lotlan", lotlan, "--map", map_file,
                           "--manager-data-dir", rig.data, "--planner-data-dir", planner_data,
                           "--token-file", token_file, "--host", "127.0.0.1", "--port", "0"],
                          log_dir=rig.tmp / "logs", name="hmi", cwd=ROOT)
    url = process.wait_until(lambda: (m := re.search(r"fleet HMI listening on (http://127\.0\.0\.1:\d+)",
                                                     child.log_tail())) and m.group(1),
                             30.0, 0.05, what="the HMI's address", child=child)
    return child, url


def test_an_operator_runs_a_load_unload_job_from_the_browser(rig: Rig, browser: Any,  # noqa: F811
                                                             capsys: pytest.CaptureFixture[str]) -> None:
    map_file = write_map(rig.tmp / "map-hmi.json", PARK)
    lotlan = rig.tmp / "hmi-jobs.tl"
    lotlan.write_text(JOBS, encoding="utf-8")
    shots = rig.tmp / "screenshots"
    sim = spawn_sim(rig, "hm-", map_file, 2, "sim-hmi")
    planner = Planner(rig, rig.tmp / "planner-hmi", lotlan, map_file, "planner-hmi")
    hmi = None
    context = None
    errors: list[str] = []
    try:
        wait_ready(rig, ["hm-0001", "hm-0002"], sim)
        planner.start()
        hmi, url = spawn_hmi(rig, lotlan, map_file, planner.data)
        context = browser.new_context(viewport={"width": 1280, "height": 1100})
        fleet = context.new_page()
        fleet.on("pageerror", lambda exc: errors.append(str(exc)))
        fleet.goto(url + "/")
        assert "/login" in fleet.url  # not logged in: the login form
        fleet.fill("#token", "not-the-token-of-this-hmi")
        fleet.click("#login")
        assert "not the token" in fleet.inner_text("main")
        fleet.fill("#token", TOKEN)
        fleet.click("#login")
        fleet.wait_for_url(url + "/")
        # both vehicles on the map, where the manager says they are
        wait_js(fleet, "document.querySelectorAll('#map g.vehicle[data-x]').length === 2", "two vehicle markers placed")
        before = fleet.evaluate("Object.fromEntries([...document.querySelectorAll('#map g.vehicle')]"
                                ".map(m => [m.dataset.key, [+m.dataset.x, +m.dataset.y]]))")
        assert set(before) == {"plan/hm-0001", "plan/hm-0002"}
        rows = fleet.inner_text("#vehicles tbody")
        assert rows.count("ONLINE") == 2 and "%" in rows and "idle" in rows
        assert rows.count("(vda5050)") == 2  # both joined by plug and play, over VDA 5050
        assert fleet.inner_text("#refused tbody").strip() == ""  # nobody refused
        shot(fleet, shots, "fleet-idle")

        station = context.new_page()
        station.on("pageerror", lambda exc: errors.append(str(exc)))
        station.goto(url + "/stations/load-1")
        wait_js(station, "document.getElementById('ready').textContent === 'no vehicle waits here'")
        assert station.is_disabled("#loaded") and station.is_disabled("#unloaded")
        station.select_option("#job-task", "transport")
        station.click("#start-job")
        wait_js(station, "document.getElementById('message').dataset.job === 'j1'", "job j1 started")
        assert "job j1 started: j1-transport-1" in station.inner_text("#message")

        # the vehicle the planner chose drives: its marker moves on the fleet page's map
        vehicle = wait_js(fleet, "(() => { const r = document.querySelector('#tasks tr[data-task=\"j1-transport-1\"]');"
                                 " return r && r.children[4].textContent; })()", "j1-transport-1 assigned")
        start = before[vehicle]
        wait_js(fleet, f"(() => {{ const m = document.querySelector('#map g.vehicle[data-key=\"{vehicle}\"]');"
                       f" return Math.hypot(+m.dataset.x - {start[0]}, +m.dataset.y - {start[1]}) > 0.5; }})()",
                f"{vehicle}'s marker moved")
        moving = fleet.evaluate(f"document.querySelector('#map g.vehicle[data-key=\"{vehicle}\"]')"
                                ".getAttribute('transform')")
        assert moving.startswith("translate(")
        shot(fleet, shots, "fleet-moving")

        # at the loading station: ready to load, Loaded
        wait_js(station, "document.getElementById('ready').textContent === 'ready to load'", "ready to load")
        assert not station.is_disabled("#loaded") and station.is_disabled("#unloaded")
        assert f"waiting: {vehicle}" in station.inner_text("#approaching")
        shot(station, shots, "station-ready-to-load")
        station.click("#loaded")
        wait_js(station, "document.getElementById('message').textContent.startsWith('Loaded: sent loaded')")
        wait_js(station, "document.getElementById('ready').textContent === 'no vehicle waits here'")

        # at the unloading station: ready to unload, Unloaded
        station.goto(url + "/stations/unload-1")
        wait_js(station, "document.getElementById('ready').textContent === 'ready to unload'", "ready to unload")
        assert station.is_disabled("#loaded") and not station.is_disabled("#unloaded")
        shot(station, shots, "station-ready-to-unload")
        station.click("#unloaded")
        wait_js(station, "document.getElementById('message').textContent.startsWith('Unloaded: sent unloaded')")
        wait_js(station, "(() => { const r = document.querySelector('#jobs tr[data-job=\"j1\"]');"
                         " return r && r.dataset.jobState === 'FINISHED'; })()", "job j1 FINISHED on the station page")
        assert "FINISHED" in station.inner_text("#jobs tbody")
        shot(station, shots, "station-finished")

        # the fleet page's order list, filtered
        fleet.select_option("#filter-state", "FINISHED")
        fleet.fill("#filter-vehicle", vehicle.split("/")[1])
        wait_js(fleet, "[...document.querySelectorAll('#tasks tbody tr')].map(r => r.dataset.task).join() === "
                       "'j1-transport-1'", "the FINISHED filter lists j1-transport-1")
        fleet.select_option("#filter-state", "open")
        wait_js(fleet, "document.querySelectorAll('#tasks tbody tr').length === 0", "no open task")
        fleet.fill("#filter-vehicle", "a b")
        wait_js(fleet, "!document.getElementById('filter-error').hidden", "the bad filter refused")
        assert "vehicle:" in fleet.inner_text("#filter-error")
        fleet.fill("#filter-vehicle", "")
        fleet.select_option("#filter-state", "")

        # a second job, withdrawn from the fleet page's order list (confirmed in the dialog)
        station.select_option("#job-task", "transport")
        station.click("#start-job")
        wait_js(station, "document.getElementById('message').dataset.job === 'j2'", "job j2 started")
        fleet.on("dialog", lambda dialog: dialog.accept())
        fleet.click('#tasks button.withdraw[data-task="j2-transport-1"]')
        wait_js(fleet, "(() => { const r = document.querySelector('#tasks tr[data-task=\"j2-transport-1\"]');"
                       " return r && r.dataset.state === 'WITHDRAWN'; })()", "j2-transport-1 WITHDRAWN")
        assert "task j2-transport-1 WITHDRAWN" in fleet.inner_text("#task-message")
        assert fleet.locator('#tasks button.withdraw').count() == 0  # nothing open is left to withdraw

        # what the planner recorded: the operator's two events, in order, and the task FINISHED
        events = [r["event"] for r in planner.journal() if r["kind"] == "event"]
        assert events == ["loaded", "unloaded"], events
        tasks = planner.tasks()
        assert tasks["j1-transport-1"]["state"] == "FINISHED"
        assert [g["state"] for g in tasks["j1-transport-1"]["legs"]] == ["DONE", "DONE"]
        assert tasks["j2-transport-1"]["state"] == "WITHDRAWN"

        # what one poll of the fleet page costs: 20 polls 0.3 s apart, past the HMI's 0.25 s sharing of
        # the upstream answers, so each asks the planner and the manager
        took = sorted(fleet.evaluate("""async () => { const out = [];
            for (let i = 0; i < 20; i++) { await new Promise(r => setTimeout(r, 300)); const t = performance.now();
                await (await fetch('/api/fleet')).json(); out.push(performance.now() - t); } return out; }"""))
        with capsys.disabled():
            print(f"\nHMI /api/fleet from Chromium, 20 polls 0.3 s apart (2 vehicles; planner and manager asked "
                  f"each time): p50 {took[len(took) // 2]:.1f} ms, max {took[-1]:.1f} ms")

        # the planner stops: the page says so, nothing breaks
        planner.stop()
        wait_js(fleet, "!document.getElementById('upstream').hidden", "the planner-down banner")
        assert "planner" in fleet.inner_text("#upstream")
        shot(fleet, shots, "fleet-planner-down")
        assert not errors, f"JavaScript errors: {errors}"
    finally:
        if context is not None:
            context.close()
        if hmi is not None:
            assert process.stop(hmi, grace=10.0) == 0, hmi.log_tail()
        planner.stop()
        assert process.stop(sim, grace=15.0) == 0, sim.log_tail()
