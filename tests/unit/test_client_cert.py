"""Client certificates of the plant CA (engine.security.client_cert, ``plantkg cert issue``)."""

from __future__ import annotations

import datetime as dt
import stat
from pathlib import Path

import pytest
from click.testing import CliRunner
from cryptography import x509
from cryptography.hazmat.primitives import serialization
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from engine.cli import main
from engine.cli.cert import cert_command
from engine.security import ca, client_cert


@pytest.fixture()
def authority(tmp_path: Path) -> ca.Ca:
    return ca.load_or_create_ca(tmp_path / "ca")


def test_the_certificate_names_the_resource_and_is_signed_by_the_plant_ca(authority: ca.Ca) -> None:
    cert_pem, key_pem = client_cert.issue_client_cert(authority, "robot1")
    cert = x509.load_pem_x509_certificate(cert_pem)
    assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == "robot1"
    cert.verify_directly_issued_by(authority.cert)  # raises if another key signed it
    assert list(cert.extensions.get_extension_for_class(x509.ExtendedKeyUsage).value) == \
        [ExtendedKeyUsageOID.CLIENT_AUTH]
    usage = cert.extensions.get_extension_for_class(x509.KeyUsage).value
    assert usage.digital_signature and not usage.key_cert_sign
    assert not cert.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    key = serialization.load_pem_private_key(key_pem, password=None)
    assert key.public_key() == cert.public_key()


def test_another_ca_does_not_verify_it(authority: ca.Ca, tmp_path: Path) -> None:
    other = ca.load_or_create_ca(tmp_path / "other-ca")
    cert = x509.load_pem_x509_certificate(client_cert.issue_client_cert(other, "robot1")[0])
    with pytest.raises(Exception):
        cert.verify_directly_issued_by(authority.cert)


def test_it_lives_the_lifetime_from_now(authority: ca.Ca) -> None:
    now = dt.datetime(2026, 1, 1, tzinfo=dt.timezone.utc)
    cert = x509.load_pem_x509_certificate(client_cert.issue_client_cert(authority, "r", now=now)[0])
    assert cert.not_valid_after_utc == now + dt.timedelta(days=client_cert.LIFETIME_DAYS)
    assert cert.not_valid_before_utc <= now


def test_each_issue_makes_a_new_key(authority: ca.Ca) -> None:
    assert client_cert.issue_client_cert(authority, "r")[1] != client_cert.issue_client_cert(authority, "r")[1]


@pytest.mark.parametrize("bad", ["", "-robot", "robot 1", "robot/1", "r\nCN=x", "a" * 65, "plantkg.agent",
                                 "robot,O=evil"])
def test_an_id_that_is_not_a_resource_name_is_refused(authority: ca.Ca, bad: str, tmp_path: Path) -> None:
    with pytest.raises(client_cert.ClientCertError) as caught:
        client_cert.write_client_bundle(authority, bad, tmp_path / "out")
    assert repr(bad) in str(caught.value) and caught.value.hint
    assert not (tmp_path / "out").exists()  # nothing written


def test_the_bundle_key_is_0600_and_the_folder_0700(authority: ca.Ca, tmp_path: Path) -> None:
    bundle = client_cert.write_client_bundle(authority, "robot1", tmp_path / "out")
    assert stat.S_IMODE(bundle.key_file.stat().st_mode) == 0o600
    assert stat.S_IMODE((tmp_path / "out").stat().st_mode) == 0o700
    assert bundle.ca_file.read_bytes() == ca.ca_pem(authority)
    cert = x509.load_pem_x509_certificate(bundle.cert_file.read_bytes())
    key = serialization.load_pem_private_key(bundle.key_file.read_bytes(), password=None)
    assert key.public_key() == cert.public_key()
    assert bundle.not_after == cert.not_valid_after_utc
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["ca.pem", "robot1.key", "robot1.pem"]


def test_the_command_writes_the_bundle_and_prints_no_key(tmp_path: Path) -> None:
    result = CliRunner().invoke(cert_command, ["issue", "robot1", "--out", str(tmp_path / "dev"),
                                               "--ca-dir", str(tmp_path / "ca")])
    assert result.exit_code == 0, result.output
    key = (tmp_path / "dev" / "robot1.key").read_text()
    assert "PRIVATE KEY" in key and key not in result.output and "PRIVATE" not in result.output
    assert str(tmp_path / "dev" / "robot1.key") in result.output
    cert = x509.load_pem_x509_certificate((tmp_path / "dev" / "robot1.pem").read_bytes())
    cert.verify_directly_issued_by(ca.load_ca(tmp_path / "ca").cert)


def test_the_command_refuses_a_bad_id_with_exit_2(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["cert", "issue", "plantkg.observer", "--out", str(tmp_path / "dev"),
                 "--ca-dir", str(tmp_path / "ca")])
    assert code == 2
    assert "plantkg's own principals" in capsys.readouterr().err
    assert not (tmp_path / "dev").exists()
