"""No page or endpoint changes anything without authentication and a CSRF token (every write
route of the app is tried), and the login works with the server's token only."""

from __future__ import annotations

import pytest
from flask import Flask
from flask.testing import FlaskClient

from engine.web.auth import CSRF_EXEMPT
from tests.web.conftest import TOKEN, login, meta_csrf

WRITE_METHODS = {"POST", "PUT", "PATCH", "DELETE"}
#: Write routes anyone may call: logging in and out changes only the caller's own session.
SESSION_ROUTES = {"auth.login", "auth.logout"}


def write_routes(app: Flask) -> list[tuple[str, str, str]]:
    """(endpoint, method, path) of every route accepting a state-changing method."""
    found = []
    for rule in app.url_map.iter_rules():
        for method in sorted((rule.methods or set()) & WRITE_METHODS):
            found.append((rule.endpoint, method, rule.rule))
    return found


def test_the_app_has_the_write_routes_we_guard(app: Flask) -> None:
    endpoints = {e for e, _m, _p in write_routes(app)}
    assert endpoints == {"api.apply", "api.refresh", "api.stop", "api.start", "api.restart",
                         "sparql.endpoint", "auth.login", "auth.logout"}
    assert CSRF_EXEMPT == {"sparql.endpoint"}  # read-only: a POST there is a query


def guarded(app: Flask) -> list[tuple[str, str, str]]:
    return [r for r in write_routes(app) if r[0] not in SESSION_ROUTES | CSRF_EXEMPT]


def test_every_write_route_refuses_without_csrf(app: Flask) -> None:
    for endpoint, method, path in guarded(app):
        r = app.test_client().open(path, method=method, json={"fingerprint": "x"})
        assert r.status_code == 403 and "CSRF" in r.get_data(as_text=True), (endpoint, r.status_code)


def test_every_write_route_refuses_a_csrf_token_without_login(app: Flask) -> None:
    for endpoint, method, path in guarded(app):
        client = app.test_client()
        csrf = meta_csrf(client)  # a real anonymous session's token
        r = client.open(path, method=method, json={"fingerprint": "x"}, headers={"X-CSRF-Token": csrf})
        assert r.status_code == 401 and r.json["error"] == "authentication required", endpoint


def test_every_write_route_refuses_a_wrong_bearer_token(app: Flask) -> None:
    for endpoint, method, path in guarded(app):
        r = app.test_client().open(path, method=method, json={"fingerprint": "x"},
                                   headers={"Authorization": "Bearer not-the-token-at-all"})
        assert r.status_code in (401, 403), endpoint


def test_logged_in_writes_need_the_session_csrf_token(app: Flask) -> None:
    client = app.test_client()
    csrf = login(client)
    assert client.post("/api/refresh").status_code == 403
    assert client.post("/api/refresh", headers={"X-CSRF-Token": "forged"}).status_code == 403
    r = client.post("/api/refresh", headers={"X-CSRF-Token": csrf})
    assert r.status_code == 200 and r.json["version"] > 0


def test_bearer_token_needs_no_csrf(client: FlaskClient) -> None:
    r = client.post("/api/refresh", headers={"Authorization": f"Bearer {TOKEN}"})
    assert r.status_code == 200


def test_apply_names_the_plan(client: FlaskClient) -> None:
    auth = {"Authorization": f"Bearer {TOKEN}"}
    assert client.post("/api/apply", json={}, headers=auth).status_code == 400
    r = client.post("/api/apply", json={"fingerprint": "0000"}, headers=auth)
    assert r.status_code == 409 and "plan changed" in r.json["error"]
    current = client.get("/api/plan").json["fingerprint"]
    r = client.post("/api/apply", json={"fingerprint": current}, headers=auth)
    assert r.status_code == 409 and "cannot be applied" in r.json["error"]  # the agents do not answer


def test_login_with_a_wrong_token_fails(client: FlaskClient) -> None:
    csrf = meta_csrf(client)
    r = client.post("/login", data={"token": "wrong", "csrf_token": csrf})
    assert r.status_code == 401 and "not the token" in r.get_data(as_text=True)
    assert client.post("/login", data={"token": TOKEN}).status_code == 403  # no CSRF token


@pytest.mark.parametrize("target, expected", [("/plan", "/plan"), ("//evil.example/", "/"),
                                              ("https://evil.example/", "/")])
def test_login_redirects_only_inside_the_app(client: FlaskClient, target: str, expected: str) -> None:
    csrf = meta_csrf(client)
    r = client.post("/login", data={"token": TOKEN, "csrf_token": csrf, "next": target})
    assert r.status_code == 302 and r.headers["Location"] == expected


def test_logout_ends_the_session(client: FlaskClient) -> None:
    csrf = login(client)
    assert client.post("/logout", data={"csrf_token": csrf}).status_code == 302
    assert client.post("/api/refresh", headers={"X-CSRF-Token": csrf}).status_code in (401, 403)


def test_cookies_and_headers(client: FlaskClient) -> None:
    login(client)
    cookie = client.get_cookie("session")
    assert cookie is not None and cookie.http_only and cookie.same_site == "Strict"
    r = client.get("/")
    assert "default-src 'self'" in r.headers["Content-Security-Policy"]
