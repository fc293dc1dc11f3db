"""Shared data of the planner's unit tests: a small map and a LoTLan program of two transports."""

from __future__ import annotations

from fleet.sim.map import SiteMap, Station

SITE = SiteMap("hall-t", 12.0, 8.0, (
    Station("load-1", 2.0, 6.0), Station("unload-1", 10.0, 6.0), Station("load-2", 2.0, 2.0),
    Station("unload-2", 10.0, 2.0), Station("park-1", 5.0, 4.0), Station("park-2", 7.0, 4.0),
))

JOBS = """\
Location loadStation
    name = "load-1"
    type = "pallet"
End

Location unloadStation
    name = "unload-1"
    type = "pallet"
End

Location otherLoad
    name = "load-2"
    type = "pallet"
End

Location otherUnload
    name = "unload-2"
    type = "pallet"
End

Event loaded
    name = "Loaded"
    type = "Boolean"
End

Event unloaded
    name = "Unloaded"
    type = "Boolean"
End

TransportOrderStep atLoad
    Location loadStation
    FinishedBy loaded == True
End

TransportOrderStep atUnload
    Location unloadStation
    FinishedBy unloaded
End

TransportOrderStep atOtherLoad
    Location otherLoad
End

TransportOrderStep atOtherUnload
    Location otherUnload
End

Task first
    Transport
    From atLoad
    To atUnload
End

Task second
    Transport
    From atOtherLoad
    To atOtherUnload
    TriggeredBy first.IsDone
End
"""
