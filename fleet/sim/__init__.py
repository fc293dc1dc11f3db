"""Simulated AGVs: kinematics, battery, map, an order executor and protocol adapters.

The vehicle core (:mod:`fleet.sim.vehicle`) is pure and stepped by a fixed tick with an injected
time, so unit tests need no sleeps; adapters (:mod:`fleet.sim.adapter`) put it on a wire
(VDA 5050 over MQTT today, the paper's channels later).
"""
