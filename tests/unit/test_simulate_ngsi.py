"""Demo helpers for context brokers: entity paths, AGV payloads the context broker accepts, the
table's "published" vs "bridge from" column (pure parts; the demo itself runs in
tests/integration/test_demo_agv.py)."""

from __future__ import annotations

import json
import threading

from engine.demo.run import _table
from engine.model import BrokerSpec
from engine.demo.simulate import AGV_PAYLOADS, Feed, Seen, payload
from engine.demo.simulate_ngsi import NgsiTap, entity_path

CB = BrokerSpec("cb", "urn:cb", "cb", "ngsi-v2", "127.0.0.3", 1026, allow_anonymous=False)
#: Orion refuses these characters in any string value ("Field syntax restrictions").
FORBIDDEN = set('<>"\'=;()')


def test_entity_path_encodes_the_id_and_asks_for_key_values() -> None:
    assert entity_path("urn:ngsi-ld:AGV:agv-1", "AGV") == \
        "/v2/entities/urn%3Angsi-ld%3AAGV%3Aagv-1?type=AGV&options=keyValues"
    assert entity_path("a%b", "T").startswith("/v2/entities/a%25b?")


def test_agv_payloads_are_json_objects_orion_accepts() -> None:
    for value in AGV_PAYLOADS:
        feed = Feed("Task planner", f"agv-1/{value}_channel", value, CB)
        for n in range(25):
            body = json.loads(payload(feed, n, n * 0.1))
            assert body["seq"] == n and set(body) > {"seq", "ts", "source"}
            strings = [v for v in json.dumps(body).split('"')[1::2]]
            assert not any(FORBIDDEN & set(s) for s in strings), (value, body)


def test_status_payload_walks_through_the_states() -> None:
    feed = Feed("AGV", "agv-1/status_channel", "status", CB)
    states = {json.loads(payload(feed, n, 0))["state"] for n in range(0, 100, 20)}
    assert states == {"driving", "loading", "unloading", "idle"}


def test_table_says_published_where_a_resource_writes_even_on_a_two_way_bridge() -> None:
    tap = NgsiTap(CB, {"agv-1/motion_channel": ("urn:m", "Motion"), "agv-1/status_channel": ("urn:s", "AGV")},
                  threading.Event())
    tap.seen["agv-1/motion_channel"] = Seen(3, {"task_id": "task-0", "ts": 1.0})
    via = {("cb", "agv-1/motion_channel"): "mqtt", ("cb", "agv-1/status_channel"): "mqtt"}
    lines = _table([tap], 0.0, via, frozenset({("cb", "agv-1/motion_channel")}))
    motion = next(line for line in lines if "motion_channel" in line)
    status = next(line for line in lines if "status_channel" in line)
    assert "published" in motion and "{'task_id': 'task-0'}" in motion  # ts is left out
    assert "bridge from mqtt" in status
