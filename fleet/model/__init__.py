"""The AGV in the knowledge graph: a vehicle's self-description (VDA 5050 factsheet or the paper's
description) checked into a frozen :class:`~fleet.model.description.AgvDescription`, the plant's
:class:`~fleet.model.binding.FleetBinding` (where the fleet lives), and the Turtle that makes the
vehicle a ``pk:Resource`` with its channels, skills and properties (:mod:`fleet.model.graph`).
The vocabulary is ``ontology/plantkg-fleet.ttl``; docs/fleet.md, "The AGV in the graph"."""
