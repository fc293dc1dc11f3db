"""Plug and play: how an unknown vehicle becomes a discovered individual of the plant.

``inbox`` turns one received MQTT message (VDA 5050 ``connection`` / ``factsheet`` / ``state``,
the paper's ``description_channel`` / ``status_channel``) into a typed event or a refusal with
its reason; ``registry`` is the pure state machine that decides what to do about an event (ask a
factsheet, join, mark unavailable, track a state) and returns effects as data; ``records`` keeps
each discovered vehicle on disk (its record and its Turtle file, written atomically); ``names``
makes file names. The fleet manager process (``fleet.manager``) puts them on the wire and runs
the reconcile.
"""
