"""The Mosquitto (MQTT) driver and its runtime: :mod:`.driver` (the agent's verbs: render, start
command, health, bridge states) and :mod:`.runtime` (``mosquitto.conf``, password and ACL files
rendered from validated values, the command line)."""
