"""The AGV side of plantkg: an application above the engine.

``fleet.vda5050`` speaks VDA 5050 2.1 (topics, QoS/retain rules, headers, schema validation,
frozen message types); ``fleet.sim`` runs simulated vehicles that speak it. Later parts (the AGV
model in the graph, plug and play, the task planner, the paper's channels) change the plant only
through the knowledge graph and the engine's API: ``engine`` never imports ``fleet``, and ``fleet``
never imports the agent, a driver or the context broker (import-linter contract in pyproject).
"""
