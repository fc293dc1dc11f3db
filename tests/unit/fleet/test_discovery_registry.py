"""fleet.discovery.registry: the rules of plug and play, event by event, with the time given."""

from __future__ import annotations

from typing import Any

import pytest

from fleet.discovery.inbox import ConnectionSeen, DescriptionSeen, Interface, StateSeen, VehicleKey, classify
from fleet.discovery.registry import (AskFactsheet, DescriptionRefused, Join, Known, Note, Refuse, Registry,
                                      SetConnection, Track)
from fleet.manager.service import describe
from tests.unit.fleet import discovery_data as d

KEY = VehicleKey(Interface.VDA5050, d.MANUFACTURER, d.SERIAL)
PAPER = VehicleKey(Interface.PAPER, "", "agv-7")


def registry() -> Registry:
    return Registry(describe, ask_every=5.0)  # the real description (fleet.model) of real factsheets


def online(key: VehicleKey = KEY, state: str = "ONLINE") -> ConnectionSeen:
    return ConnectionSeen(key, state)


def test_unknown_online_vehicle_is_asked_once_however_many_times_it_says_online() -> None:
    r = registry()
    assert r.handle(online(), 0.0) == [AskFactsheet(KEY)]
    flood = [effect for i in range(1000) for effect in r.handle(online(), 0.001 * i)]
    assert flood == []
    assert r.handle(online(), 5.1) == [AskFactsheet(KEY)]  # still no factsheet after 5 s: ask again


def test_offline_unknown_vehicle_is_not_asked() -> None:
    r = registry()
    assert r.handle(online(state="OFFLINE"), 0.0) == []
    assert r.handle(online(state="CONNECTIONBROKEN"), 0.0) == []


def test_factsheet_joins_once_and_a_second_copy_changes_nothing() -> None:
    r = registry()
    r.handle(online(), 0.0)
    [join] = r.handle(DescriptionSeen(KEY, d.factsheet()), 0.1)
    assert isinstance(join, Join) and join.new and join.connection_state == "ONLINE"
    assert join.description["serial"] == d.SERIAL and "pick" in join.description["skills"]
    assert r.handle(DescriptionSeen(KEY, d.factsheet()), 0.2) == []  # seen twice: discovered once
    assert r.handle(online(), 0.3) == []  # known: no more factsheet requests


def test_a_different_factsheet_updates_unless_pinned() -> None:
    r = registry()
    r.handle(online(), 0.0)
    r.handle(DescriptionSeen(KEY, d.factsheet()), 0.1)
    [update] = r.handle(DescriptionSeen(KEY, d.factsheet(speed=2.5)), 0.2)
    assert isinstance(update, Join) and not update.new
    pinned = registry()
    pinned.load({KEY: Known(update.description, "ONLINE", pinned=True)})
    [note] = pinned.handle(DescriptionSeen(KEY, d.factsheet(speed=0.5)), 0.3)
    assert isinstance(note, Note) and "pinned" in note.message
    assert pinned.known[KEY].description == update.description


def test_offline_and_broken_mark_a_known_vehicle_unavailable_and_online_again_available() -> None:
    r = registry()
    r.handle(online(), 0.0)
    r.handle(DescriptionSeen(KEY, d.factsheet()), 0.1)
    assert r.handle(online(state="CONNECTIONBROKEN"), 1.0) == [SetConnection(KEY, "CONNECTIONBROKEN")]
    assert r.handle(online(state="CONNECTIONBROKEN"), 1.1) == []
    assert r.handle(online(), 2.0) == [SetConnection(KEY, "ONLINE")]
    assert KEY in r.known  # never deleted


def test_a_refused_description_is_refused_once_with_its_reason_until_it_changes() -> None:
    r = registry()
    r.handle(online(), 0.0)
    bad = d.factsheet()
    bad["physicalParameters"]["speedMax"] = -1.0  # the schema allows it, the model does not
    [refuse] = r.handle(DescriptionSeen(KEY, bad), 0.1)
    assert isinstance(refuse, Refuse) and "speedMax" in refuse.reason, refuse
    assert r.handle(DescriptionSeen(KEY, bad), 0.2) == []
    [join] = r.handle(DescriptionSeen(KEY, d.factsheet()), 0.3)
    assert isinstance(join, Join)


def test_rejected_by_the_plant_forgets_it_and_refuses_the_same_factsheet() -> None:
    r = registry()
    r.handle(online(), 0.0)
    r.handle(DescriptionSeen(KEY, d.factsheet()), 0.1)
    r.reject(KEY)
    assert KEY not in r.known
    assert r.handle(DescriptionSeen(KEY, d.factsheet()), 0.2) == []
    r.handle(online(state="OFFLINE"), 0.3)
    assert r.handle(online(), 0.4) == [AskFactsheet(KEY)]  # back online: another chance


def test_paper_vehicle_joins_from_its_description_and_empty_description_means_unavailable() -> None:
    r = registry()
    assert r.handle(online(PAPER), 0.0) == []  # paper vehicles are not asked: they describe themselves
    [join] = r.handle(DescriptionSeen(PAPER, d.paper_description()), 0.1)
    assert isinstance(join, Join) and join.connection_state == "ONLINE"
    assert join.description["interface"] == "paper-channels"
    assert r.handle(DescriptionSeen(PAPER, None), 0.2) == [SetConnection(PAPER, "OFFLINE")]


def test_states_are_tracked_for_any_vehicle() -> None:
    event = classify(d.topic("state"), d.wire(d.state()))
    assert isinstance(event, StateSeen)
    assert registry().handle(event, 0.0) == [Track(KEY, event.state)]


def test_a_description_the_model_refuses_names_the_field() -> None:
    with pytest.raises(DescriptionRefused) as info:
        describe(PAPER, d.paper_description(skills="all"))
    assert "skills" in info.value.reason


def test_description_of_another_serial_than_the_topic_is_refused() -> None:
    payload: dict[str, Any] = d.paper_description("agv-8")
    with pytest.raises(DescriptionRefused, match="is not the topic's 'agv-7'"):
        describe(PAPER, payload)


def test_a_flood_of_made_up_serials_is_remembered_only_up_to_a_bound() -> None:
    r = Registry(describe, max_unknown=100)
    r.handle(online(), 0.0)
    r.handle(DescriptionSeen(KEY, d.factsheet()), 0.1)
    asked = [e for i in range(1000)
             for e in r.handle(online(VehicleKey(Interface.VDA5050, "evil", f"s-{i}")), 1.0 + i * 1e-3)]
    assert len(asked) == 1000  # each made-up vehicle is asked once ...
    assert len(r.connection) == 101 and len(r.asked) <= 101  # ... but only the newest 100 are remembered
    assert KEY in r.known and KEY in r.connection  # a discovered vehicle is never forgotten
