"""The plant CA and the server certificates it issues (engine.security.ca)."""

from __future__ import annotations

import datetime as dt
import ssl
import stat
import threading
import socket
from pathlib import Path

import pytest
from cryptography import x509
from cryptography.x509.oid import ExtendedKeyUsageOID

from engine.security import ca


def test_a_new_ca_is_a_ca_with_a_0600_key(tmp_path: Path) -> None:
    authority = ca.load_or_create_ca(tmp_path / "ca")
    assert stat.S_IMODE((tmp_path / "ca" / ca.CA_KEY).stat().st_mode) == 0o600
    assert stat.S_IMODE((tmp_path / "ca").stat().st_mode) == 0o700
    assert authority.cert.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    assert ca.load_or_create_ca(tmp_path / "ca").cert == authority.cert  # read back, not replaced


def test_processes_creating_the_ca_at_once_agree_on_one(tmp_path: Path) -> None:
    """Two agents rendering TLS brokers (or a Kafka's agent and the agent carrying a worker into
    it) create the CA at the same moment: each ends with the same CA, its key matching it. A key
    written over another's used to leave the first creator's certificate with the second's key."""
    folder, start, got, failed = tmp_path / "ca", threading.Barrier(8), [], []

    def create() -> None:
        start.wait()
        try:
            got.append(ca.load_or_create_ca(folder).cert)
        except ca.CaError as exc:
            failed.append(exc)

    threads = [threading.Thread(target=create) for _ in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(30)
    assert failed == [] and len(got) == 8 and len(set(got)) == 1
    assert ca.load_ca(folder).cert == got[0]
    assert sorted(p.name for p in folder.iterdir()) == sorted([ca.CA_CERT, ca.CA_KEY])  # nothing left aside


def test_a_server_certificate_is_issued_kept_and_renewed(tmp_path: Path) -> None:
    authority = ca.load_or_create_ca(tmp_path / "ca")
    folder = tmp_path / "broker"
    assert ca.ensure_server_cert(folder, ("127.0.0.2",), authority, name="broker b")
    cert = x509.load_pem_x509_certificate((folder / ca.CERT_FILE).read_bytes())
    cert.verify_directly_issued_by(authority.cert)
    san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert [str(ip) for ip in san.get_values_for_type(x509.IPAddress)] == ["127.0.0.2"]
    eku = cert.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value
    assert list(eku) == [ExtendedKeyUsageOID.SERVER_AUTH]
    for name in (ca.CERT_FILE, ca.KEY_FILE, ca.CA_CERT):
        assert stat.S_IMODE((folder / name).stat().st_mode) == 0o600, name
    assert not ca.ensure_server_cert(folder, ("127.0.0.2",), authority, name="broker b")  # current
    pem = (folder / ca.CERT_FILE).read_bytes()
    later = dt.datetime.now(dt.timezone.utc) + dt.timedelta(days=ca.LIFETIME_DAYS - ca.RENEW_BEFORE_DAYS + 1)
    assert ca.needs_new_cert(pem, authority, ("127.0.0.2",), later).startswith("expires")
    assert ca.needs_new_cert(pem, authority, ("127.0.0.3",)) == "for other addresses"
    other = ca.load_or_create_ca(tmp_path / "other")
    assert ca.needs_new_cert(pem, other, ("127.0.0.2",)) == "signed by another CA"
    assert ca.ensure_server_cert(folder, ("127.0.0.3",), authority, name="broker b")  # moved: new one
    assert (folder / ca.CERT_FILE).read_bytes() != pem


def test_a_client_trusting_the_ca_completes_a_handshake_and_another_is_refused(tmp_path: Path) -> None:
    authority = ca.load_or_create_ca(tmp_path / "ca")
    folder = tmp_path / "server"
    ca.ensure_server_cert(folder, ("127.0.0.1",), authority, name="server")
    server_ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    server_ctx.load_cert_chain(folder / ca.CERT_FILE, folder / ca.KEY_FILE)
    listener = socket.create_server(("127.0.0.1", 0))
    port = listener.getsockname()[1]

    def serve(count: int) -> None:
        for _ in range(count):
            conn, _ = listener.accept()
            try:
                with server_ctx.wrap_socket(conn, server_side=True) as tls:
                    tls.sendall(b"ok")
            except (ssl.SSLError, OSError):
                pass

    thread = threading.Thread(target=serve, args=(2,), daemon=True)
    thread.start()
    good = ssl.create_default_context(cafile=str(authority.cert_file))
    with socket.create_connection(("127.0.0.1", port)) as raw, good.wrap_socket(raw, server_hostname="127.0.0.1") as tls:
        assert tls.recv(2) == b"ok"
    other = ca.load_or_create_ca(tmp_path / "other")
    bad = ssl.create_default_context(cafile=str(other.cert_file))
    with socket.create_connection(("127.0.0.1", port)) as raw, pytest.raises(ssl.SSLCertVerificationError):
        bad.wrap_socket(raw, server_hostname="127.0.0.1")
    thread.join(10)
    listener.close()


def test_a_ca_brought_by_the_plant_must_be_usable(tmp_path: Path) -> None:
    folder = tmp_path / "ca"
    ca.load_or_create_ca(folder)
    (folder / ca.CA_KEY).chmod(0o644)
    with pytest.raises(ca.CaError, match="readable by others"):
        ca.load_ca(folder)
    (folder / ca.CA_KEY).chmod(0o600)
    other = ca.load_or_create_ca(tmp_path / "other")
    (folder / ca.CA_KEY).write_bytes((tmp_path / "other" / ca.CA_KEY).read_bytes())
    with pytest.raises(ca.CaError, match="is not the EC private key"):
        ca.load_ca(folder)
    assert other.folder == tmp_path / "other"
    (folder / ca.CA_CERT).write_text("not PEM")
    with pytest.raises(ca.CaError, match="unusable") as info:
        ca.load_ca(folder)
    assert "CA" in info.value.hint


def test_where_the_ca_is(tmp_path: Path) -> None:
    assert ca.ca_dir(tmp_path, {}) == tmp_path
    assert ca.ca_dir(None, {ca.CA_ENV: "/c"}) == Path("/c")
    assert ca.ca_dir(None, {"XDG_STATE_HOME": "/s"}) == Path("/s/plantkg/ca")
