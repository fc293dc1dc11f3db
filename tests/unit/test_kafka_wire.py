"""The pure parts of engine.drivers.kafka.wire, the subset of Kafka's protocol that asks one node
what it enforces: SCRAM's client computation held to the RFCs' worked examples, the readers of
Kafka's primitive types held to bytes written by hand from the protocol guide, and addresses. The
requests themselves are judged by real Kafka nodes (tests/integration/test_kafka_cluster_closed.py,
test_kafka_cluster_tls.py)."""

from __future__ import annotations

import struct

import pytest

from engine.drivers.kafka import wire

# RFC 5802 section 5 (SCRAM-SHA-1) and RFC 7677 section 3 (SCRAM-SHA-256): user "user", password
# "pencil", the client's first message (bare), the server's first, then what the client must send
# (without and with its proof) and the server's final message it must expect.
RFC_EXAMPLES = [
    ("sha1", "n=user,r=fyko+d2lbbFgONRv9qkxdawL",
     "r=fyko+d2lbbFgONRv9qkxdawL3rfcNHYJY1ZVvWVs7j,s=QSXCR+Q6sek8bf92,i=4096",
     "c=biws,r=fyko+d2lbbFgONRv9qkxdawL3rfcNHYJY1ZVvWVs7j", "v0X8v3Bz2T0CJGbJQyF0X+HI4Ts=",
     b"v=rmF9pqV8S7suAoZWja4dJRkFsKQ="),
    ("sha256", "n=user,r=rOprNGfwEbeRWgbNEkqO",
     "r=rOprNGfwEbeRWgbNEkqO%hvYDpWUa2RaTCAfuxFIlj)hNlF$k0,s=W22ZaJ0SNY7soEsUEjb6gQ==,i=4096",
     "c=biws,r=rOprNGfwEbeRWgbNEkqO%hvYDpWUa2RaTCAfuxFIlj)hNlF$k0", "dHzbZapWIk4jUhN+Ute9ytag9zjfMHgsqmmiz7AndVQ=",
     b"v=6rriTRBi23WpRR/wtup+mMhUZUn/dB5nLTJRsjl95G4="),
]


@pytest.mark.parametrize(("digest", "bare", "server_first", "without_proof", "proof", "server_final"),
                         RFC_EXAMPLES, ids=["rfc5802-sha1", "rfc7677-sha256"])
def test_scram_client_final_gives_the_rfcs_messages(digest: str, bare: str, server_first: str,
                                                     without_proof: str, proof: str, server_final: bytes) -> None:
    assert wire.scram_client_final("pencil", bare, server_first, digest) == (without_proof, proof, server_final)


def test_scram_with_another_password_gives_another_proof_and_server_signature() -> None:
    digest, bare, server_first, _, proof, server_final = RFC_EXAMPLES[1]
    _, other_proof, other_final = wire.scram_client_final("pencil2", bare, server_first, digest)
    assert other_proof != proof and other_final != server_final


def test_the_reader_reads_kafkas_primitive_types() -> None:
    data = (struct.pack(">bhiq", -2, 300, -70000, 2**40) + struct.pack(">h", 3) + b"abc" + struct.pack(">h", -1)
            + struct.pack(">i", 2) + b"\x00\x01" + bytes([0x96, 0x01])  # uvarint 150
            + bytes([4]) + "é!".encode() + bytes([0])                   # compact "é!" (3 bytes), then null
            + bytes([1, 7, 2]) + b"xy")                                  # one tagged field: tag 7, 2 bytes
    r = wire._Reader(data)
    assert (r.int8(), r.int16(), r.int32(), r.int64()) == (-2, 300, -70000, 2**40)
    assert (r.string(), r.string(), r.bytes_(), r.uvarint()) == ("abc", None, b"\x00\x01", 150)
    assert (r.compact_string(), r.compact_string()) == ("é!", None)
    r.tags()
    assert r.pos == len(data)


@pytest.mark.parametrize(("data", "read"), [(b"\x00", "int16"), (struct.pack(">h", 5) + b"abc", "string"),
                                          (bytes([0x80]), "uvarint"), (bytes([9]) + b"ab", "compact_string")],
                         ids=["short int16", "string past the end", "unterminated uvarint", "compact past the end"])
def test_the_reader_refuses_an_answer_cut_short(data: bytes, read: str) -> None:
    with pytest.raises(ValueError):
        getattr(wire._Reader(data), read)()


@pytest.mark.parametrize(("address", "expected"), [
    ("127.0.0.2:9092", ("127.0.0.2", 9092)), ("[::1]:9093", ("::1", 9093)), ("node-1:1", ("node-1", 1))])
def test_split_address(address: str, expected: tuple[str, int]) -> None:
    assert wire.split_address(address) == expected


@pytest.mark.parametrize("address", ["127.0.0.2", ":9092", "host:", "host:x1"])
def test_split_address_refuses(address: str) -> None:
    with pytest.raises(ValueError):
        wire.split_address(address)
