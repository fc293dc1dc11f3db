"""The fleet manager process (``python -m fleet.manager``): plug and play, orders, status.

It connects to the plant's MQTT broker (found from the plant through the AGV model's binding),
discovers vehicles (``fleet.discovery``), reconciles the plant with the discovered vehicles
(``apply_step``: pipeline + apply, one run per batch of joins), sends VDA 5050 orders
(``orders``, through a small HTTP API on loopback, ``api``), tracks each vehicle's last state and
writes ``<data-dir>/status.json`` for the dashboard (``status``). ``service`` ties them together.
"""
