"""Fixtures of the web tests: a plant state, the app, a test client, the app served over HTTP.

Unit-level fixtures use an agents directory whose every agent is a closed port on loopback (the
agents are then *unreachable*, as the engine reports them), so no test here needs a broker.
"""

from __future__ import annotations

import shutil
import threading
from collections.abc import Iterator
from pathlib import Path

import pytest
from flask import Flask
from flask.testing import FlaskClient
from werkzeug.serving import make_server

from engine import netutil
from engine.agents_config import AgentDirectory, AgentEntry
from engine.web.app import WebConfig, create_app
from engine.web.plant_state import PlantState
from engine.web.sparql_protocol import Limits

ROOT = Path(__file__).resolve().parents[2]
TOKEN = "web-test-token-0123456789"


def closed_directory(hosts: tuple[str, ...] = ("127.0.0.2", "127.0.0.3")) -> AgentDirectory:
    """Agents that do not answer: every host's URL is a port nobody listens on."""
    port = netutil.free_port()
    return AgentDirectory(entries={h: AgentEntry(h, f"http://127.0.0.1:{port}", token="x" * 20) for h in hosts})


@pytest.fixture
def plant_file(tmp_path: Path) -> Path:
    target = tmp_path / "robot-cell.ttl"
    shutil.copy(ROOT / "ontology" / "examples" / "robot-cell.ttl", target)
    return target


@pytest.fixture
def state(plant_file: Path) -> Iterator[PlantState]:
    directory = closed_directory()
    plant_state = PlantState([str(plant_file)], None, directory_loader=lambda _p: directory)
    plant_state.reload()
    yield plant_state
    plant_state.close()


def make_app(state: PlantState, limits: Limits = Limits()) -> Flask:
    app = create_app(WebConfig(state=state, token=TOKEN, limits=limits))
    app.config["TESTING"] = True
    return app


@pytest.fixture
def app(state: PlantState) -> Iterator[Flask]:
    made = make_app(state)
    yield made
    made.extensions["plantkg_sparql"].close()  # its SPARQL worker processes, if a query started any


@pytest.fixture
def client(app: Flask) -> FlaskClient:
    return app.test_client()


def login(client: FlaskClient, token: str = TOKEN) -> str:
    """Log ``client`` in through the form; returns the session's CSRF token."""
    page = client.get("/login")
    csrf = _meta_csrf(page.get_data(as_text=True))
    response = client.post("/login", data={"token": token, "csrf_token": csrf, "next": "/plan"})
    assert response.status_code == 302, response.get_data(as_text=True)
    return _meta_csrf(client.get("/plan").get_data(as_text=True))


def _meta_csrf(html: str) -> str:
    marker = '<meta name="csrf-token" content="'
    start = html.index(marker) + len(marker)
    return html[start:html.index('"', start)]


def meta_csrf(client: FlaskClient) -> str:
    """The CSRF token of ``client``'s session (as a page carries it)."""
    return _meta_csrf(client.get("/login").get_data(as_text=True))


@pytest.fixture
def served(app: Flask) -> Iterator[str]:
    """The app on a free loopback port; yields its base URL."""
    server = make_server("127.0.0.1", 0, app, threaded=True)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{server.server_port}"
    server.shutdown()
    thread.join()
    server.server_close()
