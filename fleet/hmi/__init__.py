"""The operators' screens (HMI) of the fleet: a page per station and a fleet page with a live map.

A small Flask app of its own (the engine never imports fleet, so it cannot live in engine/web),
with the dashboard's login scheme: one token file, a login form, a signed session cookie, a CSRF
token on every POST. It reads the task planner's HTTP API (tasks, jobs, events) and the fleet
manager's (vehicles); the browser polls its JSON endpoints every 0.5 s.

- :mod:`fleet.hmi.auth`: token file, login, CSRF, ``login_required``.
- :mod:`fleet.hmi.upstream`: the planner's and the manager's APIs; ``UpstreamDown`` when they do not answer.
- :mod:`fleet.hmi.views`: pure functions: what a station's page and the fleet page show.
- :mod:`fleet.hmi.app`: ``create_app(HmiConfig)``: pages and JSON endpoints.
- :mod:`fleet.hmi.__main__`: ``python -m fleet.hmi`` / ``plantkg fleet hmi``.

See docs/fleet-hmi.md.
"""
