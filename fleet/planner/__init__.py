"""The task planner of the fleet manager (issue 12): LoTLan transport orders become tasks that
vehicles carry out.

Layers, bottom to top (each module one job):

- :mod:`states` — the task and sub-task states and every allowed transition, as data;
- :mod:`model` — frozen :class:`Task` / :class:`Leg` (a sub-task) and their JSON form;
- :mod:`split` — the paper's Fig. 5: motions then actions, split where an action would be
  followed by a motion; a wait action ends a sub-task;
- :mod:`build` — a LoTLan ``Task`` with its steps resolved to map stations -> a planner Task;
- :mod:`conditions` — TriggeredBy / FinishedBy evaluated against fired events and done tasks;
- :mod:`machine` — the pure transitions (assign, send, track, vehicle lost, finish), each checked
  against :mod:`states`;
- :mod:`assign` + ``assign.rq`` — which vehicle takes a task: a SPARQL query over the plant graph
  and the live vehicle states (nearest fitting idle vehicle first, rows logged);
- :mod:`plantview` — the plant graph (plant files + the manager's discovered vehicles), reloaded
  when a discovered file changes;
- :mod:`journal` — the write-ahead log (JSON lines, fsync'd per transition) and its replay;
- :mod:`vehicles` — the manager's vehicle list with their last VDA 5050 states (HTTP; 503 = wait),
  paper vehicles joined with their AGV entity on the context broker;
- :mod:`dispatch` — a sub-task as a VDA 5050 order through the manager's API, or the paper's
  items (:mod:`paper`, ids in :mod:`paperids`) on the context broker; ``cancelOrder``;
- :mod:`ngsi` — tasks as NGSI-v2 entities (type ``Task``) on the context broker, over HTTP;
- :mod:`ngsi_tls` — how every NGSI client of the planner trusts an ``https://`` context broker
  (``--ngsi-ca-file``: a ``pk:tls`` one's plant CA) and the check of its certificate at start;
- :mod:`event_sources` (shared parsing and counts), :mod:`events_mqtt`, :mod:`events_ngsi` — LoTLan
  events fired from MQTT (``plantkg/events/<name>``) and from ``Event`` entities on the context
  broker (a subscription notifying a loopback endpoint of the planner), through the same journaled
  path as ``POST /v1/events``;
- :mod:`service`, :mod:`api`, ``__main__`` — the process: ``python -m fleet.planner``.

docs/fleet-manager.md ("Task planner") describes the states, the query and the API.
"""
