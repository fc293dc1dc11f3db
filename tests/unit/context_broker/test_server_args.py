"""The context broker's command line (engine.context_broker.server): loopback unless told, a
token or an explicit --open, clear refusals."""

from __future__ import annotations

from pathlib import Path

import pytest

from engine.context_broker.server import ConfigError, check_host, main, parse_args, read_tls, read_token


@pytest.mark.parametrize("host", ["127.0.0.1", "127.0.0.5", "::1", "localhost"])
def test_loopback_hosts_are_fine(host: str) -> None:
    check_host(host, allow_remote=False)


@pytest.mark.parametrize(("host", "words"), [("0.0.0.0", "not a loopback"), ("192.168.1.4", "--allow-remote"),
                                             ("example.org", "not an IP address")])
def test_other_hosts_need_allow_remote(host: str, words: str) -> None:
    with pytest.raises(ConfigError, match=words):
        check_host(host, allow_remote=False)
    check_host(host, allow_remote=True)


def test_token_from_file_or_open(tmp_path: Path) -> None:
    token = tmp_path / "token"
    token.write_text("  abc123 \nsecond line ignored\n")
    assert read_token(parse_args(["--data-dir", "d", "--token-file", str(token)])) == "abc123"
    assert read_token(parse_args(["--data-dir", "d", "--open"])) is None
    for argv, words in ((["--data-dir", "d"], "--token-file"),
                        (["--data-dir", "d", "--open", "--token-file", str(token)], "not both"),
                        (["--data-dir", "d", "--token-file", str(tmp_path / "none")], "cannot read")):
        with pytest.raises(ConfigError, match=words):
            read_token(parse_args(argv))
    (tmp_path / "empty").write_text("\n")
    with pytest.raises(ConfigError, match="empty"):
        read_token(parse_args(["--data-dir", "d", "--token-file", str(tmp_path / "empty")]))


def test_main_refuses_a_remote_host_before_touching_the_data_dir(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--host", "0.0.0.0", "--data-dir", str(tmp_path / "d"), "--open"]) == 2
    assert "loopback" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


def test_fsync_is_off_unless_asked() -> None:
    assert parse_args(["--data-dir", "d"]).fsync is False
    assert parse_args(["--data-dir", "d", "--fsync"]).fsync is True


def test_closed_kafkas_are_addresses(tmp_path: Path) -> None:
    """``--closed-kafka HOST:PORT``: where kafka:// notifications log in as plantkg."""
    from engine.context_broker.server import read_closed_kafkas  # noqa: PLC0415
    args = parse_args(["--data-dir", "d", "--open", "--closed-kafka", "127.0.0.4:9092",
                       "--closed-kafka", "[0:0::1]:9093"])
    assert read_closed_kafkas(args) == {("127.0.0.4", 9092), ("::1", 9093)}
    assert read_closed_kafkas(parse_args(["--data-dir", "d", "--open"])) == frozenset()
    for bad in ("127.0.0.4", "kafka.local:9092", "127.0.0.4:0"):
        with pytest.raises(ConfigError, match=f"--closed-kafka '{bad}'"):
            read_closed_kafkas(parse_args(["--data-dir", "d", "--open", "--closed-kafka", bad]))


def test_tls_kafkas_are_addresses(tmp_path: Path) -> None:
    """``--tls-kafka HOST:PORT``: where kafka:// notifications speak TLS (the plant CA)."""
    from engine.context_broker.server import read_plant_kafkas  # noqa: PLC0415
    kafkas = read_plant_kafkas(parse_args(["--data-dir", "d", "--open", "--tls-kafka", "127.0.0.4:9093",
                                           "--closed-kafka", "127.0.0.4:9093", "--closed-kafka", "127.0.0.5:9092"]))
    assert kafkas.tls == {("127.0.0.4", 9093)} and kafkas.closed == {("127.0.0.4", 9093), ("127.0.0.5", 9092)}
    with pytest.raises(ConfigError, match="--tls-kafka 'kafka.local:9093'"):
        read_plant_kafkas(parse_args(["--data-dir", "d", "--open", "--tls-kafka", "kafka.local:9093"]))


def test_tls_needs_both_the_certificate_and_its_key(tmp_path: Path) -> None:
    base = ["--data-dir", str(tmp_path), "--open"]
    assert read_tls(parse_args(base)) is None
    with pytest.raises(ConfigError, match="together"):
        read_tls(parse_args([*base, "--tls-cert", str(tmp_path / "cert.pem")]))
    with pytest.raises(ConfigError, match="cannot load"):
        read_tls(parse_args([*base, "--tls-cert", str(tmp_path / "no.pem"), "--tls-key", str(tmp_path / "no.key")]))
