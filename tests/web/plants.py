"""A small plant with only Mosquitto brokers (fast to start), written for the web tests.

Two machines (127.0.0.2 and 127.0.0.3), one Mosquitto broker each, a robot and a sensor sending to
them; broker A bridges the robot's position topic (which both carry) to broker B (a Mosquitto bridge).
Both admit anonymous clients (the tests publish anonymously; closed brokers: docs/security.md).
"""

from __future__ import annotations

from pathlib import Path

MACHINES = ("127.0.0.2", "127.0.0.3")

_TEMPLATE = """@prefix pk: <https://w3id.org/plantkg/ontology#> .
@prefix : <https://w3id.org/plantkg/examples/web-test#> .

:robot-type a pk:ResourceType ; pk:id "robot-type" ; pk:name "Robot" .
:robot a pk:Resource ; pk:id "robot-1" ; pk:name "Robot 1" ; pk:isType :robot-type ;
    pk:sendsTo :mqtt-a ; pk:publishes :position .
:sensor a pk:Resource ; pk:id "sensor-1" ; pk:name "Sensor 1" ; pk:isType :robot-type ;
    pk:sendsTo :mqtt-b ; pk:publishes :temperature .
:position a pk:Topic ; pk:id "position" ; pk:name "cell.robot-1.position" ;
    pk:valueTopic "position" ; pk:typeTopic "json" .
:temperature a pk:Topic ; pk:id "temperature" ; pk:name "cell.sensor-1.temperature" ;
    pk:valueTopic "temperature" ; pk:typeTopic "json" .
:mqtt-a a pk:Broker ; pk:id "mqtt-a" ; pk:name "Cell MQTT A" ; pk:brokerType "mosquitto" ;
    pk:ip "127.0.0.2" ; pk:port {port_a} ; pk:hasTopic :position ; pk:bridgesTo :mqtt-b ;
    pk:allowAnonymous true .
:mqtt-b a pk:Broker ; pk:id "mqtt-b" ; pk:name "Cell MQTT B" ; pk:brokerType "mosquitto" ;
    pk:ip "127.0.0.3" ; pk:port {port_b} ; pk:hasTopic :temperature , :position ;
    pk:allowAnonymous true .
"""


def write_mosquitto_plant(path: Path, port_a: int, port_b: int) -> Path:
    path.write_text(_TEMPLATE.replace("{port_a}", str(port_a)).replace("{port_b}", str(port_b)),
                    encoding="utf-8")
    return path
