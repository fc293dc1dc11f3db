"""``/sparql``: the SPARQL 1.1 Protocol's query operation over the served plant (read-only).

Query by GET (``?query=``), by POST form-encoded (``query=``) or by POST with the query as an
``application/sparql-query`` body; ``default-graph-uri`` / ``named-graph-uri`` choose the dataset
(default: the union of every graph). Status codes: 400 no or malformed query, 403 an update,
406 no acceptable result format, 413 an answer over the result limit, 415 a POST of another
content type, 429 this client runs too many queries at once, 503 the timeout (or too many queries
in all). Errors are plain text: the message, then a hint; 429 and 503 for load carry Retry-After.

The client of the per-client limit is the logged-in user (a session or the bearer token), else the
remote address (behind a reverse proxy every request has the proxy's address: limit there).
Limits, timeouts and why queries run in worker processes: engine.web.sparql_protocol,
docs/security.md.
"""

from __future__ import annotations

from typing import Any

from flask import Blueprint, Response, current_app, redirect, request, session, url_for
from werkzeug.datastructures import MultiDict

from engine.web import auth
from engine.web.sparql_protocol import Dataset, QueryRunner, SparqlError, negotiate, offered_types, serialize

bp = Blueprint("sparql", __name__)
_FORM = "application/x-www-form-urlencoded"
_QUERY = "application/sparql-query"
_UPDATE = "application/sparql-update"


def _error(status: int, message: str, hint: str | None = None, retry_after_s: int | None = None) -> Response:
    body = message + (f"\nhint: {hint}" if hint else "") + "\n"
    response = Response(body, status=status, mimetype="text/plain")
    if retry_after_s is not None:
        response.headers["Retry-After"] = str(retry_after_s)
    return response


def client_of_request() -> str:
    """Who the per-client query limit counts this request for: the user, else the address."""
    if auth.authenticated():
        return f"user {session.get('user') or 'operator'}"
    return f"address {request.remote_addr or 'unknown'}"


def _read_request() -> tuple[str, MultiDict[str, str]]:
    """The query text and the parameters holding the dataset; raises SparqlError."""
    if request.method == "GET":
        params = request.args
        if "update" in params:
            raise SparqlError(403, "SPARQL updates are not allowed: this endpoint is read-only")
        texts = params.getlist("query")
    else:
        mimetype = request.mimetype
        if mimetype == _UPDATE or (mimetype == _FORM and "update" in request.form):
            raise SparqlError(403, "SPARQL updates are not allowed: this endpoint is read-only",
                              "edit the plant's Turtle files instead; the server re-reads them")
        if mimetype == _FORM:
            params = request.form
            texts = params.getlist("query")
        elif mimetype == _QUERY:
            params = request.args
            texts = [request.get_data(as_text=True)]
        else:
            raise SparqlError(415, f"a SPARQL query cannot be sent as {mimetype or 'a body without a Content-Type'}",
                              f"POST it as {_FORM} (query=...) or as {_QUERY}")
    if len(texts) != 1 or not texts[0].strip():
        raise SparqlError(400, "give exactly one query" if texts else "no query given",
                          "pass ?query=SELECT ... (GET), query=... (form POST) or a sparql-query body")
    return texts[0], params


@bp.route("/sparql", methods=["GET", "POST"], endpoint="endpoint")
def endpoint() -> Any:
    if (request.method == "GET" and not request.args
            and request.accept_mimetypes.best_match(["text/html", "application/sparql-results+json"]) == "text/html"):
        return redirect(url_for("dashboard.query_page"))
    try:
        text, params = _read_request()
        dataset = Dataset(tuple(params.getlist("default-graph-uri")), tuple(params.getlist("named-graph-uri")))
        snap = current_app.config["PLANTKG_STATE"].snapshot
        if snap.plant is None:
            raise SparqlError(503, "no plant is loaded yet", "see the dashboard for the load error")
        runner: QueryRunner = current_app.extensions["plantkg_sparql"]
        answer = runner.execute(snap.plant.store, text, dataset,
                                guard=current_app.config["PLANTKG_STATE"].store_lock.reading,
                                version=snap.version, client=client_of_request())
    except SparqlError as exc:
        return _error(exc.status, exc.message, exc.hint, exc.retry_after_s)
    except ValueError as exc:  # a dataset parameter that is no IRI
        return _error(400, f"bad default-graph-uri or named-graph-uri: {exc}")
    chosen = negotiate(request.accept_mimetypes, answer.kind)
    if chosen is None:
        return _error(406, f"no acceptable format for this {answer.kind} answer "
                           f"(Accept: {request.headers.get('Accept', '')})",
                      "accept one of " + ", ".join(offered_types(answer.kind)))
    media_type, _ = chosen
    response = Response(serialize(answer, media_type), mimetype=media_type)
    response.headers["Vary"] = "Accept"
    return response
