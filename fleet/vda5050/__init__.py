"""VDA 5050 2.1 message layer: topics and their MQTT rules, headers, JSON-schema checks, messages.

Pure functions and frozen dataclasses, no MQTT client: the simulator's adapter (and later the fleet
manager) put them on the wire.
"""

VERSION = "2.1.0"
