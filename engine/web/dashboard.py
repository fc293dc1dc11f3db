"""The dashboard's pages: overview (tables and the graph), plan with Apply, validation, SPARQL.

Pages are rendered once by the server; the overview then renders itself from ``/api/status``
(static/dashboard.js polls it with an ETag), so the tables and the graph follow the plant live.
"""

from __future__ import annotations

import json
from typing import Any

import click
from flask import Blueprint, current_app, render_template

from engine.model import Action, Change
from engine.render.plan import SIGNS, summary_line
from engine.web.examples import EXAMPLES
from engine.web.plant_state import PlantState
from kg.render import validation_text

bp = Blueprint("dashboard", __name__)


def _state() -> PlantState:
    return current_app.config["PLANTKG_STATE"]


def change_rows(change: Change) -> list[dict[str, Any]]:
    """Field by field: before, after, and whether it differs (for the plan's before/after table)."""
    before, after = change.before or {}, change.after or {}
    keys = list(after) + [k for k in before if k not in after]
    return [{"field": k, "before": _show(before.get(k)), "after": _show(after.get(k)),
             "changed": before.get(k) != after.get(k)} for k in keys]


def _show(value: Any) -> str:
    return "" if value is None else json.dumps(value, ensure_ascii=False)


@bp.get("/")
def overview() -> Any:
    snap = _state().snapshot
    return render_template("overview.html", status_json=snap.status_json.decode(), version=snap.version)


@bp.get("/plan")
def plan_page() -> Any:
    snap = _state().snapshot
    changes = []
    if snap.plan is not None:
        changes = [{"address": c.address, "action": c.action.value, "sign": SIGNS[c.action],
                    "reason": c.reason, "rows": change_rows(c)}
                   for c in snap.plan.changes if c.action is not Action.NOOP]
    return render_template("plan.html", snap=snap, changes=changes,
                           summary=summary_line(snap.plan) if snap.plan else None)


@bp.get("/validation")
def validation_page() -> Any:
    snap = _state().snapshot
    text = None
    if snap.report is not None:
        text = click.unstyle(validation_text(snap.report, snap.plant.prefixes if snap.plant else {}))
    return render_template("validation.html", snap=snap, text=text)


@bp.get("/query")
def query_page() -> Any:
    return render_template("query.html", examples=EXAMPLES)
