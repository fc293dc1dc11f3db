"""MQTT 5 packets as bytes, both ways: what the bridge worker's MQTT client sends and reads.

Pure functions and one incremental :class:`Decoder`, no socket, so every packet and every way a
stream can be cut is unit-tested without a broker. Only what a bridge worker needs is here
(OASIS MQTT 5.0, chapter 3): CONNECT/CONNACK, SUBSCRIBE/SUBACK, UNSUBSCRIBE, PUBLISH at QoS 0 or 1,
PUBACK, PINGREQ/PINGRESP and DISCONNECT. Properties the worker does not use are skipped by type,
so a broker sending more of them is read correctly.

Why not paho's parser: paho reads each packet with three ``recv`` calls and builds a
``Properties`` object per message; at 20,000 messages/s that alone took more CPU than the rest of
the worker (``benchmarks.bench_bridge``). :class:`Decoder` cuts every complete packet out of one
large read.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

CONNECT, CONNACK, PUBLISH, PUBACK = 1, 2, 3, 4
SUBSCRIBE, SUBACK, UNSUBSCRIBE, UNSUBACK = 8, 9, 10, 11
PINGREQ, PINGRESP, DISCONNECT = 12, 13, 14

PINGREQ_PACKET = b"\xc0\x00"
DISCONNECT_PACKET = b"\xe0\x00"   # normal disconnection: the session stays on the broker

# Property identifiers used here (MQTT 5.0, 2.2.2.2).
SESSION_EXPIRY = 0x11
SERVER_KEEP_ALIVE = 0x13
RECEIVE_MAXIMUM = 0x21
TOPIC_ALIAS = 0x23
REASON_STRING = 0x1F

#: The wire type of each property identifier: 1/2/4 byte integers, a variable byte integer,
#: UTF-8 string, binary data, string pair.
_PROPERTY_TYPES: dict[int, str] = {
    0x01: "b", 0x02: "4", 0x03: "s", 0x08: "s", 0x09: "d", 0x0B: "v", 0x11: "4", 0x12: "s",
    0x13: "2", 0x15: "s", 0x16: "d", 0x17: "b", 0x18: "4", 0x19: "b", 0x1A: "s", 0x1C: "s",
    0x1F: "s", 0x21: "2", 0x22: "2", 0x23: "2", 0x24: "b", 0x25: "b", 0x26: "p", 0x27: "4",
    0x28: "b", 0x29: "b", 0x2A: "b",
}

_U16 = struct.Struct("!H")
_U32 = struct.Struct("!I")


class MalformedPacket(ValueError):
    """The broker sent bytes that are not a valid MQTT 5 packet: the connection is dropped."""


@dataclass(frozen=True)
class Packet:
    """One packet read from the stream: its type, the four flag bits, the bytes after the fixed
    header."""

    kind: int
    flags: int
    body: bytes


@dataclass(frozen=True)
class Publish:
    topic: str
    payload: bytes
    qos: int
    mid: int          # 0 for QoS 0
    retain: bool
    dup: bool


@dataclass(frozen=True)
class Connack:
    session_present: bool
    reason: int
    properties: dict[int, object]

    @property
    def receive_maximum(self) -> int:
        """How many QoS>0 messages the broker takes unacknowledged (absent: 65535)."""
        return int(self.properties.get(RECEIVE_MAXIMUM, 65535))  # type: ignore[call-overload]


# --- encoding ---------------------------------------------------------------------------------

def varint(n: int) -> bytes:
    """A variable byte integer (remaining length, property length)."""
    if not 0 <= n <= 268_435_455:
        raise ValueError(f"{n} does not fit a variable byte integer")
    out = bytearray()
    while True:
        byte, n = n & 0x7F, n >> 7
        out.append(byte | (0x80 if n else 0))
        if not n:
            return bytes(out)


def _utf8(text: str) -> bytes:
    data = text.encode("utf-8")
    if len(data) > 65535:
        raise ValueError("an MQTT string is at most 65535 bytes")
    return _U16.pack(len(data)) + data


def _binary(data: bytes) -> bytes:
    if len(data) > 65535:
        raise ValueError("MQTT binary data is at most 65535 bytes")
    return _U16.pack(len(data)) + data


def _packet(first: int, body: bytes) -> bytes:
    return bytes((first,)) + varint(len(body)) + body


def connect(client_id: str, keepalive: int, *, clean_start: bool, session_expiry: int,
            receive_maximum: int, username: str | None = None, password: bytes | None = None) -> bytes:
    flags = (0x02 if clean_start else 0) | (0x80 if username is not None else 0) \
        | (0x40 if password is not None else 0)
    props = bytes((SESSION_EXPIRY,)) + _U32.pack(session_expiry) \
        + bytes((RECEIVE_MAXIMUM,)) + _U16.pack(receive_maximum)
    body = _utf8("MQTT") + bytes((5, flags)) + _U16.pack(keepalive) + varint(len(props)) + props \
        + _utf8(client_id)
    if username is not None:
        body += _utf8(username)
    if password is not None:
        body += _binary(password)
    return _packet(CONNECT << 4, body)


def subscribe(mid: int, topics: list[tuple[str, int, bool]]) -> bytes:
    """(topic filter, QoS, no_local) each; retain handling 0, retain-as-published off."""
    body = _U16.pack(mid) + b"\x00" + b"".join(
        _utf8(topic) + bytes((qos | (0x04 if no_local else 0),)) for topic, qos, no_local in topics)
    return _packet((SUBSCRIBE << 4) | 0x02, body)


def unsubscribe(mid: int, topics: list[str]) -> bytes:
    return _packet((UNSUBSCRIBE << 4) | 0x02, _U16.pack(mid) + b"\x00" + b"".join(_utf8(t) for t in topics))


def publish(topic: str, payload: bytes, qos: int, mid: int = 0, retain: bool = False) -> bytes:
    head = _utf8(topic) + (_U16.pack(mid) if qos else b"") + b"\x00"
    return _packet((PUBLISH << 4) | (qos << 1) | (1 if retain else 0), head + payload)


def puback(mid: int) -> bytes:
    """A PUBACK with reason 0 (success), which MQTT 5 lets us send as two bytes of packet id."""
    return b"\x40\x02" + _U16.pack(mid)


# --- decoding ---------------------------------------------------------------------------------

class Decoder:
    """Cuts complete packets out of a byte stream fed in pieces of any size."""

    def __init__(self) -> None:
        self._buf = bytearray()

    def feed(self, data: bytes) -> list[Packet]:
        buf = self._buf
        buf += data
        packets: list[Packet] = []
        pos, end = 0, len(buf)
        while end - pos >= 2:
            first = buf[pos]
            length, shift, i, complete = 0, 0, pos + 1, False
            while i < end:
                byte = buf[i]
                i += 1
                length |= (byte & 0x7F) << shift
                if not byte & 0x80:
                    complete = True
                    break
                shift += 7
                if shift > 21:
                    raise MalformedPacket("remaining length longer than 4 bytes")
            if not complete or end - i < length:
                break  # the rest of this packet has not arrived yet
            packets.append(Packet(first >> 4, first & 0x0F, bytes(buf[i:i + length])))
            pos = i + length
        if pos:
            del buf[:pos]
        return packets


def _varint_at(data: bytes, pos: int) -> tuple[int, int]:
    value, shift = 0, 0
    while True:
        if pos >= len(data):
            raise MalformedPacket("truncated variable byte integer")
        byte = data[pos]
        value |= (byte & 0x7F) << shift
        pos += 1
        if not byte & 0x80:
            return value, pos
        shift += 7
        if shift > 21:
            raise MalformedPacket("variable byte integer longer than 4 bytes")


def properties(data: bytes, pos: int) -> tuple[dict[int, object], int]:
    """The property block at ``pos``: {identifier: value} (the last of repeated ones) and the
    position after it."""
    length, pos = _varint_at(data, pos)
    end = pos + length
    if end > len(data):
        raise MalformedPacket("properties run past the packet")
    found: dict[int, object] = {}
    while pos < end:
        ident = data[pos]
        kind = _PROPERTY_TYPES.get(ident)
        pos += 1
        value: object
        if kind == "b":
            value, pos = data[pos], pos + 1
        elif kind == "2":
            value, pos = _U16.unpack_from(data, pos)[0], pos + 2
        elif kind == "4":
            value, pos = _U32.unpack_from(data, pos)[0], pos + 4
        elif kind == "v":
            value, pos = _varint_at(data, pos)
        elif kind in ("s", "d"):
            n = _U16.unpack_from(data, pos)[0]
            raw = data[pos + 2:pos + 2 + n]
            value, pos = (raw.decode("utf-8", "replace") if kind == "s" else raw), pos + 2 + n
        elif kind == "p":
            n = _U16.unpack_from(data, pos)[0]
            m = _U16.unpack_from(data, pos + 2 + n)[0]
            value = (data[pos + 2:pos + 2 + n].decode("utf-8", "replace"),
                     data[pos + 4 + n:pos + 4 + n + m].decode("utf-8", "replace"))
            pos += 4 + n + m
        else:
            raise MalformedPacket(f"unknown property identifier 0x{ident:02x}")
        found[ident] = value
    if pos != end:
        raise MalformedPacket("properties do not end where their length says")
    return found, end


def parse_connack(body: bytes) -> Connack:
    if len(body) < 2:
        raise MalformedPacket("CONNACK too short")
    props, _ = properties(body, 2) if len(body) > 2 else ({}, 2)
    return Connack(bool(body[0] & 0x01), body[1], props)


def parse_publish(flags: int, body: bytes) -> Publish:
    qos = (flags >> 1) & 0x03
    if qos > 2:
        raise MalformedPacket("PUBLISH with QoS 3")
    n = _U16.unpack_from(body, 0)[0]
    topic_end = 2 + n
    pos = topic_end
    mid = 0
    if qos:
        mid = _U16.unpack_from(body, pos)[0]
        pos += 2
    # the property block: its length, then skipped (a topic alias is never set up by this client)
    if pos < len(body) and body[pos] == 0:
        pos += 1
    else:
        props, pos = properties(body, pos)
        if TOPIC_ALIAS in props:
            raise MalformedPacket("topic alias sent although the client allowed none")
    try:
        topic = body[2:topic_end].decode("utf-8")
    except UnicodeDecodeError:
        raise MalformedPacket("PUBLISH topic is not UTF-8") from None
    return Publish(topic, body[pos:], qos, mid, bool(flags & 0x01), bool(flags & 0x08))


def parse_ack(body: bytes) -> tuple[int, int]:
    """(packet id, reason code) of a PUBACK; a two-byte PUBACK means success (0)."""
    if len(body) < 2:
        raise MalformedPacket("acknowledgement too short")
    return _U16.unpack_from(body, 0)[0], body[2] if len(body) > 2 else 0


def parse_suback(body: bytes) -> tuple[int, list[int]]:
    """(packet id, one reason code per filter: the granted QoS, or >= 0x80 refused)."""
    mid = _U16.unpack_from(body, 0)[0]
    _props, pos = properties(body, 2)
    return mid, list(body[pos:])


def parse_disconnect(body: bytes) -> tuple[int, str | None]:
    """(reason code, the broker's reason string if any) of a DISCONNECT from the broker."""
    if not body:
        return 0, None
    reason = body[0]
    if len(body) > 1:
        props, _ = properties(body, 1)
        text = props.get(REASON_STRING)
        return reason, text if isinstance(text, str) else None
    return reason, None
