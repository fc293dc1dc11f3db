"""Finding the real parts: overrides, and errors that tell the user to run `make setup`."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from engine import parts
from engine.errors import (
    JavaMissingError,
    KafkaMissingError,
    MosquittoMissingError,
    PartMissingError,
)


def test_kafka_version_matches_pom() -> None:
    pom = (parts.repo_root() / "third_party" / "kafka" / "pom.xml").read_text()
    assert re.search(r"<kafka.version>(.*?)</kafka.version>", pom).group(1) == parts.KAFKA_VERSION


def test_kafka_home_default_and_override(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.delenv("PLANTKG_KAFKA_HOME", raising=False)
    assert parts.kafka_home() == parts.repo_root() / ".plantkg" / "kafka" / parts.KAFKA_VERSION
    monkeypatch.setenv("PLANTKG_KAFKA_HOME", str(tmp_path))
    assert parts.kafka_home() == tmp_path


def test_kafka_missing_says_make_setup(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("PLANTKG_KAFKA_HOME", str(tmp_path))
    with pytest.raises(KafkaMissingError) as err:
        parts.kafka_parts()
    assert isinstance(err.value, PartMissingError)
    assert "make setup" in str(err.value) and str(tmp_path / "libs") in str(err.value)


def test_kafka_parts_distribution_layout(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    (tmp_path / "libs").mkdir()
    (tmp_path / "libs" / "kafka_2.13-3.9.1.jar").touch()
    (tmp_path / "config").mkdir()
    (tmp_path / "config" / "log4j.properties").touch()
    monkeypatch.setenv("PLANTKG_KAFKA_HOME", str(tmp_path))
    found = parts.kafka_parts()
    assert found.log4j_config == tmp_path / "config" / "log4j.properties"
    assert found.tools_log4j_config is None
    assert found.classpath == f"{tmp_path / 'libs'}/*"


def test_mosquitto_and_java_missing(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.delenv("JAVA_HOME", raising=False)
    monkeypatch.setattr(parts, "SBIN_DIRS", (tmp_path,))
    with pytest.raises(MosquittoMissingError, match="make setup"):
        parts.mosquitto_binary()
    with pytest.raises(JavaMissingError, match="make setup"):
        parts.java_binary()


def test_mosquitto_found_in_sbin(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    fake = tmp_path / "mosquitto"
    fake.write_text("#!/bin/sh\n")
    fake.chmod(0o755)
    monkeypatch.setenv("PATH", "/nonexistent")
    monkeypatch.setattr(parts, "SBIN_DIRS", (tmp_path,))
    assert parts.mosquitto_binary() == fake
