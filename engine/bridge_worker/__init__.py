"""The bridge worker: a process, run and supervised by the agent of the MQTT broker it is attached
to, that forwards topics between Mosquitto and Kafka (``mqtt-kafka``), or between Mosquitto and an
NGSI-v2 context broker (``mqtt-ngsi``: :mod:`engine.bridge_worker.ngsi_worker`), at least once.

``python -m engine.bridge_worker <state_dir>/worker.json`` (see :mod:`engine.bridge_worker.config`)
writes its health and counters to ``<state_dir>/stats.json`` (:mod:`engine.bridge_worker.stats`).
docs/bridges.md explains the guarantees and how they are kept.
"""
