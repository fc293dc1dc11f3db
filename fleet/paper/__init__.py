"""The second paper's AGV interface: five MQTT channels per vehicle, and their messages.

``<agv-id>/{action_channel, motion_channel, movement_channel, status_channel,
description_channel}`` (the paper's section 4.3). The vehicle subscribes to motion and action
items (the paper's Listing 1 and its action commands), publishes its status, movement and
description. :mod:`channels` names the topics and their MQTT rules, :mod:`schemas` checks received
payloads against the JSON schemas kept in ``schemas/`` (also the context broker's MQTT
notification around them), :mod:`messages` holds the frozen message types, :mod:`tasks` the task
state machine of the paper's Fig. 5.
"""
