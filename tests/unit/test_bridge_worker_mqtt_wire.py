"""MQTT 5 packets of the bridge worker's client, as bytes: encodings checked byte by byte against
the OASIS MQTT 5.0 layout, and the decoder against streams cut at every possible point."""

from __future__ import annotations

import pytest

from engine.bridge_worker import mqtt_wire as wire


@pytest.mark.parametrize(("n", "encoded"), [
    (0, b"\x00"), (127, b"\x7f"), (128, b"\x80\x01"), (16_383, b"\xff\x7f"), (16_384, b"\x80\x80\x01"),
    (2_097_151, b"\xff\xff\x7f"), (2_097_152, b"\x80\x80\x80\x01"), (268_435_455, b"\xff\xff\xff\x7f"),
])
def test_variable_byte_integers_follow_the_spec_table(n: int, encoded: bytes) -> None:
    assert wire.varint(n) == encoded
    assert wire._varint_at(encoded, 0) == (n, len(encoded))


def test_a_variable_byte_integer_past_four_bytes_is_refused() -> None:
    with pytest.raises(ValueError):
        wire.varint(268_435_456)
    with pytest.raises(wire.MalformedPacket):
        wire._varint_at(b"\xff\xff\xff\xff\x01", 0)


def test_connect_carries_session_expiry_receive_maximum_and_the_client_id() -> None:
    packet = wire.connect("w1", 10, clean_start=False, session_expiry=604_800, receive_maximum=1000)
    body = (b"\x00\x04MQTT" b"\x05" b"\x00" b"\x00\x0a"           # protocol, level 5, flags, keep-alive
            b"\x08" b"\x11\x00\x09\x3a\x80" b"\x21\x03\xe8"        # properties: expiry 604800, rcv max 1000
            b"\x00\x02w1")
    assert packet == b"\x10" + bytes((len(body),)) + body


def test_connect_with_clean_start_and_credentials_sets_their_flags_and_fields() -> None:
    packet = wire.connect("c", 5, clean_start=True, session_expiry=0, receive_maximum=10,
                          username="u", password=b"pw")
    [decoded] = wire.Decoder().feed(packet)
    assert (decoded.kind, decoded.flags) == (wire.CONNECT, 0)
    assert decoded.body[7] == 0x80 | 0x40 | 0x02   # username, password, clean start
    assert decoded.body.endswith(b"\x00\x01c\x00\x01u\x00\x02pw")


def test_subscribe_sets_qos_and_no_local_per_topic() -> None:
    packet = wire.subscribe(7, [("a/b", 1, True), ("c", 0, False)])
    assert packet == b"\x82\x0d" b"\x00\x07" b"\x00" b"\x00\x03a/b\x05" b"\x00\x01c\x00"


def test_publish_and_puback_layouts() -> None:
    assert wire.publish("t", b"hi", 1, 258) == b"\x32\x08\x00\x01t\x01\x02\x00hi"
    assert wire.publish("t", b"hi", 0) == b"\x30\x06\x00\x01t\x00hi"
    assert wire.publish("t", b"", 0, retain=True) == b"\x31\x04\x00\x01t\x00"
    assert wire.puback(258) == b"\x40\x02\x01\x02"


def test_the_decoder_gives_the_same_packets_however_the_stream_is_cut() -> None:
    big = wire.publish("big/topic", b"x" * 300, 1, 9)            # a two-byte remaining length
    stream = wire.puback(1) + big + wire.PINGREQ_PACKET + wire.publish("t", b"", 0) + b"\xd0\x00"
    whole = wire.Decoder().feed(stream)
    assert [p.kind for p in whole] == [wire.PUBACK, wire.PUBLISH, wire.PINGREQ, wire.PUBLISH, wire.PINGRESP]
    for cut in range(1, len(stream)):
        decoder = wire.Decoder()
        assert decoder.feed(stream[:cut]) + decoder.feed(stream[cut:]) == whole, cut
    decoder = wire.Decoder()
    assert [p for i in range(len(stream)) for p in decoder.feed(stream[i:i + 1])] == whole


def test_publish_is_read_back_with_its_fields() -> None:
    [packet] = wire.Decoder().feed(wire.publish("cell/a", b"\x00payload\n", 1, 65535))
    msg = wire.parse_publish(packet.flags, packet.body)
    assert msg == wire.Publish("cell/a", b"\x00payload\n", 1, 65535, False, False)
    [packet] = wire.Decoder().feed(b"\x39\x04\x00\x01t\x00")   # QoS 0, dup bit and retain set
    assert wire.parse_publish(packet.flags, packet.body) == wire.Publish("t", b"", 0, 0, True, True)


def test_publish_properties_are_skipped_by_type_and_a_topic_alias_is_refused() -> None:
    props = (b"\x02\x00\x00\x00\x3c"                      # message expiry interval (4 bytes)
             b"\x26\x00\x01k\x00\x02vv"                   # user property (string pair)
             b"\x03\x00\x04text"                          # content type (string)
             b"\x0b\x81\x01")                             # subscription identifier (varint 129)
    body = b"\x00\x01t\x00\x05" + wire.varint(len(props)) + props + b"data"
    assert wire.parse_publish(0x02, body) == wire.Publish("t", b"data", 1, 5, False, False)
    aliased = b"\x00\x01t\x00\x05\x03\x23\x00\x01data"
    with pytest.raises(wire.MalformedPacket, match="topic alias"):
        wire.parse_publish(0x02, aliased)


def test_connack_reads_session_present_reason_and_receive_maximum() -> None:
    ack = wire.parse_connack(b"\x01\x00\x05\x21\x00\x14\x24\x01")   # receive max 20, max QoS 1
    assert (ack.session_present, ack.reason, ack.receive_maximum) == (True, 0, 20)
    assert wire.parse_connack(b"\x00\x00\x00").receive_maximum == 65535   # absent: the maximum
    refused = wire.parse_connack(b"\x00\x87\x00")
    assert (refused.session_present, refused.reason) == (False, 0x87)


def test_acks_suback_and_disconnect() -> None:
    assert wire.parse_ack(b"\x00\x07") == (7, 0)
    assert wire.parse_ack(b"\x00\x07\x10\x00") == (7, 0x10)            # no matching subscribers
    assert wire.parse_suback(b"\x00\x03\x00\x01\x80") == (3, [1, 0x80])
    assert wire.parse_disconnect(b"") == (0, None)
    assert wire.parse_disconnect(b"\x8e\x05\x1f\x00\x02hi") == (0x8E, "hi")


def test_malformed_input_raises_a_typed_error() -> None:
    with pytest.raises(wire.MalformedPacket):
        wire.Decoder().feed(b"\x30\xff\xff\xff\xff\x01")             # remaining length of 5 bytes
    with pytest.raises(wire.MalformedPacket, match="unknown property"):
        wire.properties(b"\x02\x7f\x00", 0)
    with pytest.raises(wire.MalformedPacket):
        wire.properties(b"\x05\x21\x00", 0)                          # runs past the packet
    with pytest.raises(wire.MalformedPacket):
        wire.parse_ack(b"\x00")
