"""The dashboard of a running plant in a real headless Chromium (Debian's, driven by Playwright).

Real parts: two ``plantkg agent`` processes (127.0.0.2, 127.0.0.3) that run real Mosquitto
brokers, and ``plantkg serve`` as its own process. The tests run in file order on one server:
the overview shows each broker (absent before apply), the graph and the tables; a SPARQL query
runs from its page; a logged-in person presses Apply on the plan, confirms, and sees the brokers
and their bridge turn running on an overview left open (live update, no reload); then a changed
file shows a new plan. Screenshots go to the pytest tmp dir (``screenshots/``).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import urllib.request
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from engine import netutil, process
from engine.agent.local import plantkg_command
from engine.cli import main
from tests.integration.agents import AgentFleet, start_agents
from tests.web.plants import MACHINES, write_mosquitto_plant

pytestmark = pytest.mark.integration

CHROMIUM = shutil.which("chromium") or "/usr/bin/chromium"
TOKEN = "browser-test-token-0123456789"
WAIT_MS = 60_000


@dataclass
class Served:
    url: str
    plant: Path
    fleet: AgentFleet
    shots: Path
    child: process.Child

    def status(self) -> dict:
        with urllib.request.urlopen(self.url + "/api/status", timeout=10) as answer:
            return json.loads(answer.read())


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    tmp = tmp_path_factory.mktemp("web-browser")
    plant = write_mosquitto_plant(tmp / "plant.ttl", netutil.free_port(MACHINES[0]), netutil.free_port(MACHINES[1]))
    fleet = start_agents(list(MACHINES), tmp)
    child = None
    try:
        token_file = tmp / "web-token"
        token_file.write_text(TOKEN + "\n")
        os.chmod(token_file, 0o600)
        port = netutil.free_port()
        child = process.spawn([*plantkg_command(), "serve", plant, "--listen", f"127.0.0.1:{port}",
                               "--agents", fleet.agents_file, "--token-file", token_file,
                               "--observe-interval", "1"], log_dir=tmp / "logs", name="serve")
        served = Served(f"http://127.0.0.1:{port}", plant, fleet, tmp / "screenshots", child)
        process.wait_until(lambda: served.status()["observed_at"], 60.0, 0.1, what="plantkg serve", child=child,
                           ignore=(OSError,))
        yield served
    finally:
        if child is not None:
            process.stop(child)
        fleet.brokers()  # remember their pids: fleet.stop checks none survives
        assert main(["destroy", str(plant), "--agents", str(fleet.agents_file), "--yes"]) == 0
        fleet.stop()


@pytest.fixture(scope="module")
def browser(served: Served) -> Iterator[object]:
    if not Path(CHROMIUM).exists():
        pytest.fail(f"no Chromium at {CHROMIUM}: run `make setup` (it installs Debian's chromium)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        chromium = pw.chromium.launch(executable_path=CHROMIUM, headless=True)
        yield chromium
        chromium.close()


@pytest.fixture
def page(browser):  # type: ignore[no-untyped-def]
    context = browser.new_context(viewport={"width": 1280, "height": 1400})
    page = context.new_page()
    page.set_default_timeout(WAIT_MS)
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    yield page
    context.close()
    assert not errors, f"JavaScript errors: {errors}"


def shot(page, served: Served, name: str) -> None:  # type: ignore[no-untyped-def]
    served.shots.mkdir(exist_ok=True)
    page.screenshot(path=str(served.shots / f"{name}.png"), full_page=True)
    assert (served.shots / f"{name}.png").stat().st_size > 10_000


def wait_js(page, expression: str) -> object:  # type: ignore[no-untyped-def]
    """Poll ``expression`` in the page until it is truthy (Playwright's wait_for_function evaluates
    strings with eval, which the dashboard's Content-Security-Policy rightly forbids)."""
    return process.wait_until(lambda: page.evaluate(expression), WAIT_MS / 1000, 0.2, what=expression)


def broker_status(page, broker_id: str) -> str:  # type: ignore[no-untyped-def]
    return page.inner_text(f'#brokers td[data-status-of="{broker_id}"]')


def test_overview_shows_each_broker_and_the_graph(page, served: Served) -> None:  # type: ignore[no-untyped-def]
    page.goto(served.url + "/")
    for broker_id in ("mqtt-a", "mqtt-b"):
        assert broker_status(page, broker_id) == "absent"
    rows = page.inner_text("#brokers tbody")
    assert "127.0.0.2" in rows and "mosquitto" in rows
    assert page.inner_text("#validation-summary").startswith("valid")
    assert "6 to create" in page.inner_text("#plan-summary")  # two brokers, three topics, a bridge
    assert page.inner_text('#bridges td[data-status-of="bridge.mqtt-a.mqtt-b"]') == "absent"
    assert "cell.robot-1.position (out)" in page.inner_text("#bridges tbody")
    assert page.inner_text("#machines tbody").count("answered") == 2
    wait_js(page, "window.plantGraph && window.plantGraph.nodes().length === 4")
    nodes = page.evaluate("window.plantGraph.nodes().map(n => n.id() + '=' + n.data('status')).sort()")
    assert nodes == ["broker:mqtt-a=absent", "broker:mqtt-b=absent", "resource:robot-1=resource",
                     "resource:sensor-1=resource"]
    assert page.evaluate("window.plantGraph.edges('[type = \"bridge\"]').map(e => e.source().id() + '>' + e.target().id())") \
        == ["broker:mqtt-a>broker:mqtt-b"]
    zoom = page.evaluate("window.plantGraph.zoom()")
    page.mouse.move(400, 600)
    page.mouse.wheel(0, -400)
    wait_js(page, f"window.plantGraph.zoom() !== {zoom}")
    shot(page, served, "overview-before-apply")


def test_sparql_query_from_the_page(page, served: Served) -> None:  # type: ignore[no-untyped-def]
    page.goto(served.url + "/query")
    page.select_option("#examples", label="Which resource sends where")
    page.click("#run")
    page.wait_for_selector("#results tbody tr")
    header = page.inner_text("#results thead")
    assert "resource" in header and "broker" in header
    body = page.inner_text("#results tbody")
    assert "robot-1" in body and "mqtt-a" in body and "sensor-1" in body
    shot(page, served, "sparql-results")
    page.fill("#query", "SELEC nonsense")
    page.click("#run")
    page.wait_for_selector("#query-error:not([hidden])")
    assert "400" in page.inner_text("#query-error")
    shot(page, served, "sparql-error")


def test_apply_from_the_plan_changes_the_status_live(page, browser, served: Served) -> None:  # type: ignore[no-untyped-def]
    overview = browser.new_page()
    overview.set_default_timeout(WAIT_MS)
    overview.goto(served.url + "/")
    assert broker_status(overview, "mqtt-a") == "absent"
    page.goto(served.url + "/plan")
    assert page.query_selector("#apply") is None and "Log in" in page.inner_text("main")
    page.goto(served.url + "/login?next=/plan")
    page.fill("#token", TOKEN)
    page.click("#login")
    page.wait_for_url(served.url + "/plan")
    assert "+ broker.mqtt-a" in page.inner_text("main") and "Plan: 6 to create" in page.inner_text("#plan-line")
    dialogs: list[str] = []
    page.on("dialog", lambda d: (dialogs.append(d.message), d.accept()))
    page.click("#apply")
    wait_js(page, "document.getElementById('apply-state').textContent === 'done'")
    assert dialogs and "Apply this plan" in dialogs[0]
    assert "Apply complete" in page.inner_text("#apply-log")
    shot(page, served, "plan-applied")
    wait_js(overview, """document.querySelector('#brokers td[data-status-of="mqtt-a"]').textContent === 'running'
        && document.querySelector('#brokers td[data-status-of="mqtt-b"]').textContent === 'running'""")
    assert overview.evaluate("window.plantGraph.getElementById('broker:mqtt-a').data('status')") == "running"
    wait_js(overview, """document.querySelector('#bridges td[data-status-of="bridge.mqtt-a.mqtt-b"]').textContent === 'running'""")
    assert netutil.port_open(MACHINES[0], served.status()["brokers"][0]["port"])
    shot(overview, served, "overview-after-apply")
    overview.close()


def test_a_changed_file_shows_a_new_plan(page, served: Served) -> None:  # type: ignore[no-untyped-def]
    page.goto(served.url + "/")
    text = served.plant.read_text()
    new_port = netutil.free_port(MACHINES[1])
    served.plant.write_text(re.sub(r'(pk:ip "127\.0\.0\.3" ; pk:port )\d+', rf"\g<1>{new_port}", text))
    wait_js(page, "document.getElementById('plan-summary').textContent.includes('1 to replace')")
    page.goto(served.url + "/plan")
    row = page.inner_text(".change.replace")
    assert "broker.mqtt-b" in row and str(new_port) in row
    shot(page, served, "plan-after-edit")
