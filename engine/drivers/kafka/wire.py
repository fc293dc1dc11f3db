"""Kafka's wire protocol, just enough to ask ONE node of a cluster what it enforces (issue 13).

Why not confluent-kafka: librdkafka sends DescribeAcls and DescribeUserScramCredentials to the
"controller" of its metadata (rdkafka_admin.c: the default target), and a KRaft broker names a
random live broker there (KafkaApis.handleTopicMetadataRequest). An AdminClient whose bootstrap is
one node therefore still asks whichever node that happens to be, and cannot tell whether THIS
node has applied the users and ACLs from the metadata log. So plantkg opens a connection to the
node's own listener and speaks the protocol (https://kafka.apache.org/protocol): size-prefixed
frames, a request header, answers in order on the same connection.

The requests, at versions Kafka 3.x serves:

- SaslHandshake v1 (key 17) + SaslAuthenticate v1 (36): log in as plantkg (PLAIN), or as a user
  (SCRAM-SHA-512, RFC 5802 / RFC 7677) exactly as that user's client would;
- DescribeAcls v1 (29): the ACLs this node's authorizer holds;
- DescribeUserScramCredentials v0 (50; a "flexible" version: compact strings, tagged fields):
  the SCRAM users of this node's metadata image.

A node that does not answer, or answers garbage, raises :class:`BrokerUnavailableError`; a Kafka
error code raises :class:`DriverError` naming it. TLS trusts the given CA only and checks the
node's address against its certificate (like the driver's AdminClient).
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import secrets
import socket
import ssl
import struct

from engine.errors import BrokerUnavailableError, DriverError

SASL_HANDSHAKE, SASL_AUTHENTICATE, DESCRIBE_ACLS, DESCRIBE_SCRAM = 17, 36, 29, 50
#: Kafka error codes this module tells apart (org.apache.kafka.common.protocol.Errors).
SASL_AUTHENTICATION_FAILED = 58
_ANY = 1  # the ANY value of the resource type, pattern type, operation and permission filters
#: ScramMechanism codes in DescribeUserScramCredentials (1: SCRAM-SHA-256, 2: SCRAM-SHA-512).
SCRAM_SHA_512 = 2
CLIENT_ID = "plantkg-access-check"
MAX_FRAME = 64 << 20

#: (resource type, name, pattern type, principal, host, operation, permission) — Kafka's codes.
AclKey = tuple[int, str, int, str, str, int, int]


class _Reader:
    """Reads Kafka's primitive types from a response body, front to back."""

    def __init__(self, data: bytes) -> None:
        self.data, self.pos = data, 0

    def take(self, n: int) -> bytes:
        if n < 0 or self.pos + n > len(self.data):
            raise ValueError(f"a field of {n} bytes runs past the end of a {len(self.data)}-byte answer")
        out = self.data[self.pos:self.pos + n]
        self.pos += n
        return out

    def int8(self) -> int:
        return int(struct.unpack(">b", self.take(1))[0])

    def int16(self) -> int:
        return int(struct.unpack(">h", self.take(2))[0])

    def int32(self) -> int:
        return int(struct.unpack(">i", self.take(4))[0])

    def int64(self) -> int:
        return int(struct.unpack(">q", self.take(8))[0])

    def uvarint(self) -> int:
        out = shift = 0
        while True:
            byte = self.take(1)[0]
            out |= (byte & 0x7F) << shift
            if not byte & 0x80:
                return out
            shift += 7
            if shift > 28:
                raise ValueError("a varint longer than 5 bytes")

    def string(self) -> str | None:
        n = self.int16()
        return None if n < 0 else self.take(n).decode("utf-8")

    def bytes_(self) -> bytes | None:
        n = self.int32()
        return None if n < 0 else self.take(n)

    def compact_string(self) -> str | None:
        n = self.uvarint() - 1
        return None if n < 0 else self.take(n).decode("utf-8")

    def tags(self) -> None:
        """Skip a tagged-fields section (none of them is read here)."""
        for _ in range(self.uvarint()):
            self.uvarint()
            self.take(self.uvarint())


def _string(value: str | None) -> bytes:
    if value is None:
        return struct.pack(">h", -1)
    raw = value.encode("utf-8")
    return struct.pack(">h", len(raw)) + raw


def scram_client_final(password: str, client_first_bare: str, server_first: str,
                       digest: str = "sha512") -> tuple[str, str, bytes]:
    """The client's side of a SCRAM exchange after the server's first message (RFC 5802 section 3;
    RFC 7677 for SHA-256, Kafka's SCRAM-SHA-512 with ``digest="sha512"``): the final message
    without its proof, the proof (base64), and the server's final message that proves it knows the
    password (``v=...``). Pure: held to the examples of RFC 5802 and RFC 7677 in tests/unit/test_kafka_wire.py."""
    fields = dict(part.split("=", 1) for part in server_first.split(",") if "=" in part)
    salted = hashlib.pbkdf2_hmac(digest, password.encode(), base64.b64decode(fields["s"]), int(fields["i"]))
    client_key = hmac.digest(salted, b"Client Key", digest)
    without_proof = f"c=biws,r={fields['r']}"
    auth_message = f"{client_first_bare},{server_first},{without_proof}".encode()
    signature = hmac.digest(hashlib.new(digest, client_key).digest(), auth_message, digest)
    proof = base64.b64encode(bytes(a ^ b for a, b in zip(client_key, signature))).decode()
    server_signature = hmac.digest(hmac.digest(salted, b"Server Key", digest), auth_message, digest)
    return without_proof, proof, b"v=" + base64.b64encode(server_signature)


def split_address(address: str) -> tuple[str, int]:
    """``host:port`` or ``[v6]:port`` (engine.values.host_in_url's form) as (host, port)."""
    host, _, port = address.rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(f"{address!r} is not host:port")
    return host.strip("[]"), int(port)


class NodeConnection:
    """One connection to one Kafka node's listener (a context manager); each method one request
    and its answer, within ``timeout`` seconds each."""

    def __init__(self, address: str, *, tls: ssl.SSLContext | None = None, timeout: float = 5.0) -> None:
        """``tls``: the client context to speak TLS with (:func:`engine.security.https.client_context`:
        the plant CA only, the node's address checked); None: plain TCP."""
        self.address = address
        host, port = split_address(address)
        self._correlation = 0
        try:
            sock = socket.create_connection((host, port), timeout=timeout)
            if tls is not None:
                sock = tls.wrap_socket(sock, server_hostname=host)
        except (OSError, ssl.SSLError) as exc:
            raise BrokerUnavailableError(f"Kafka node {address} did not answer: {exc}",
                                         hint="the node may be starting; try again") from exc
        self._sock = sock

    def __enter__(self) -> NodeConnection:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._sock.close()

    # --- requests ------------------------------------------------------------------------

    def login_plain(self, user: str, password: str) -> None:
        """SASL/PLAIN (plantkg's own principal); DriverError if the node refuses it."""
        self._handshake("PLAIN")
        code, message, _ = self._authenticate(b"\0" + user.encode() + b"\0" + password.encode())
        if code:
            raise DriverError(f"Kafka node {self.address} refused plantkg's login (error {code}: {message})",
                              hint="the principal key of this machine must be the plant's")

    def login_scram(self, user: str, password: str) -> bool:
        """SCRAM-SHA-512 as ``user``, as its client would (RFC 5802): True if the node accepts
        the password (and proves it knows it), False if it refuses the login."""
        self._handshake("SCRAM-SHA-512")
        nonce = base64.b64encode(secrets.token_bytes(24)).decode()
        bare = f"n={user.replace('=', '=3D').replace(',', '=2C')},r={nonce}"
        code, _, first = self._authenticate(("n,," + bare).encode())
        if code == SASL_AUTHENTICATION_FAILED:
            return False
        if code:
            raise DriverError(f"Kafka node {self.address}: SCRAM login of {user!r} failed with error {code}")
        server_first = first.decode()
        fields = dict(part.split("=", 1) for part in server_first.split(",") if "=" in part)
        if not fields.get("r", "").startswith(nonce):
            raise BrokerUnavailableError(f"Kafka node {self.address} answered a SCRAM login with another nonce")
        without_proof, proof, expected_final = scram_client_final(password, bare, server_first)
        code, _, final = self._authenticate(f"{without_proof},p={proof}".encode())
        if code == SASL_AUTHENTICATION_FAILED:
            return False
        if code:
            raise DriverError(f"Kafka node {self.address}: SCRAM login of {user!r} failed with error {code}")
        return hmac.compare_digest(final, expected_final)

    def acls(self) -> set[AclKey]:
        """Every ACL this node's authorizer holds (DescribeAcls v1, all filters ANY)."""
        body = bytes([_ANY]) + _string(None) + bytes([_ANY]) + _string(None) + _string(None) + bytes([_ANY, _ANY])
        r = self._call(DESCRIBE_ACLS, 1, body)
        r.int32()  # throttle time
        self._check(r.int16(), r.string(), "listing its ACLs")
        out: set[AclKey] = set()
        for _ in range(r.int32()):
            rtype, name, pattern = r.int8(), r.string() or "", r.int8()
            for _ in range(r.int32()):
                principal, host, operation, permission = r.string() or "", r.string() or "", r.int8(), r.int8()
                out.add((rtype, name, pattern, principal, host, operation, permission))
        return out

    def scram_users(self) -> set[str]:
        """The users that have a SCRAM-SHA-512 credential in this node's metadata image."""
        r = self._call(DESCRIBE_SCRAM, 0, b"\x00\x00", flexible=True)  # users: null (all); no tags
        r.int32()  # throttle time
        self._check(r.int16(), r.compact_string(), "listing its SCRAM users")
        out: set[str] = set()
        for _ in range(r.uvarint() - 1):
            user, code, message = r.compact_string() or "", r.int16(), r.compact_string()
            self._check(code, message, f"describing SCRAM user {user!r}")
            mechanisms = []
            for _ in range(r.uvarint() - 1):
                mechanisms.append(r.int8())
                r.int32()  # iterations
                r.tags()
            r.tags()
            if SCRAM_SHA_512 in mechanisms:
                out.add(user)
        return out

    # --- framing -------------------------------------------------------------------------

    def _handshake(self, mechanism: str) -> None:
        r = self._call(SASL_HANDSHAKE, 1, _string(mechanism))
        code = r.int16()
        offered = [r.string() for _ in range(r.int32())]
        self._check(code, f"it offers {offered}", f"starting a {mechanism} login")

    def _authenticate(self, token: bytes) -> tuple[int, str | None, bytes]:
        r = self._call(SASL_AUTHENTICATE, 1, struct.pack(">i", len(token)) + token)
        code, message, answer = r.int16(), r.string(), r.bytes_() or b""
        r.int64()  # session lifetime
        return code, message, answer

    def _check(self, code: int, message: str | None, doing: str) -> None:
        if code:
            raise DriverError(f"Kafka node {self.address} answered error {code} while {doing}"
                              + (f": {message}" if message else ""))

    def _call(self, key: int, version: int, body: bytes, *, flexible: bool = False) -> _Reader:
        """Send one request, read its answer; the body's reader past the response header."""
        self._correlation += 1
        header = struct.pack(">hhi", key, version, self._correlation) + _string(CLIENT_ID)
        if flexible:
            header += b"\x00"  # request header v2: no tagged fields
        frame = header + body
        try:
            self._sock.sendall(struct.pack(">i", len(frame)) + frame)
            size = struct.unpack(">i", self._read(4))[0]
            if not 4 <= size <= MAX_FRAME:
                raise ValueError(f"an answer of {size} bytes")
            r = _Reader(self._read(size))
            if r.int32() != self._correlation:
                raise ValueError("an answer to another request")
            if flexible:
                r.tags()  # response header v1
            return r
        except (OSError, ValueError) as exc:
            raise BrokerUnavailableError(f"Kafka node {self.address} did not answer request {key} v{version}: {exc}",
                                         hint="the node may be starting or restarting; try again") from exc

    def _read(self, n: int) -> bytes:
        chunks: list[bytes] = []
        while n:
            chunk = self._sock.recv(n)
            if not chunk:
                raise ConnectionResetError("the node closed the connection")
            chunks.append(chunk)
            n -= len(chunk)
        return b"".join(chunks)

