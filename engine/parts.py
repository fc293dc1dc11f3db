"""Find the real parts that ``make setup`` (scripts/setup.sh) installs.

- Mosquitto: the Debian package's binary, on PATH or in /usr/sbin (not on a normal user's PATH).
- Java: ``java`` on PATH, else ``$JAVA_HOME/bin/java``.
- Kafka: jars resolved from Maven Central into ``<repo>/.plantkg/kafka/<version>/libs`` plus the
  log4j configs setup writes beside them. ``PLANTKG_KAFKA_HOME`` points at another folder with the
  same layout; an unpacked Apache Kafka distribution also works (its ``config/*log4j.properties``).

Each finder raises a :class:`engine.errors.PartMissingError` subclass that tells the user to run
``make setup``; none of them installs anything.
"""

from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path

from engine.errors import JavaMissingError, KafkaMissingError, MosquittoMissingError

#: The Kafka version setup installs; must equal <kafka.version> in third_party/kafka/pom.xml
#: (a unit test checks it).
KAFKA_VERSION = "3.9.1"

#: Where Debian puts the mosquitto binary (not on a non-root user's PATH).
SBIN_DIRS = (Path("/usr/sbin"), Path("/usr/local/sbin"))


def repo_root() -> Path:
    """The checkout that holds ``engine/`` (plantkg is installed editable)."""
    return Path(__file__).resolve().parent.parent


def mosquitto_binary() -> Path:
    """The ``mosquitto`` executable: PATH first, then /usr/sbin and /usr/local/sbin."""
    found = shutil.which("mosquitto")
    if found:
        return Path(found)
    for folder in SBIN_DIRS:
        candidate = folder / "mosquitto"
        if candidate.is_file() and os.access(candidate, os.X_OK):
            return candidate
    raise MosquittoMissingError("mosquitto", "PATH, " + ", ".join(map(str, SBIN_DIRS)))


#: Where Mosquitto's dynamic security plugin may be (Debian's package: /usr/lib/<arch>/).
PLUGIN_DIRS = (Path("/usr/lib"), Path("/usr/local/lib"), Path("/usr/lib64"))


def mosquitto_dynsec_plugin() -> Path:
    """Mosquitto's dynamic security plugin (``mosquitto_dynamic_security.so``, shipped with
    Debian's ``mosquitto``): closed brokers load it for their users and ACLs."""
    name = "mosquitto_dynamic_security.so"
    for folder in PLUGIN_DIRS:
        for candidate in (folder / name, *sorted(folder.glob(f"*/{name}"))):
            if candidate.is_file():
                return candidate
    raise MosquittoMissingError(name, ", ".join(f"{d}, {d}/*" for d in PLUGIN_DIRS))


def java_binary() -> Path:
    """The ``java`` executable: PATH first, then ``$JAVA_HOME/bin/java``."""
    found = shutil.which("java")
    if found:
        return Path(found)
    java_home = os.environ.get("JAVA_HOME")
    if java_home:
        candidate = Path(java_home) / "bin" / "java"
        if candidate.is_file() and os.access(candidate, os.X_OK):
            return candidate
    raise JavaMissingError("java", "PATH, $JAVA_HOME/bin")


@dataclass(frozen=True)
class KafkaParts:
    """An installed Kafka: its jars and log4j 1.2 configs (None: the JVM's default, no logs)."""

    version: str
    home: Path
    libs: Path
    log4j_config: Path | None
    tools_log4j_config: Path | None

    @property
    def classpath(self) -> str:
        """A ``-cp`` value; the JVM expands the trailing ``*`` itself (no shell involved)."""
        return str(self.libs / "*")


def kafka_home(version: str = KAFKA_VERSION) -> Path:
    """``$PLANTKG_KAFKA_HOME`` if set, else ``<repo>/.plantkg/kafka/<version>``."""
    env = os.environ.get("PLANTKG_KAFKA_HOME")
    return Path(env).resolve() if env else repo_root() / ".plantkg" / "kafka" / version


def kafka_parts(version: str = KAFKA_VERSION) -> KafkaParts:
    """The Kafka install of :func:`kafka_home`; raises if its ``libs/`` holds no broker jar."""
    home = kafka_home(version)
    libs = home / "libs"
    if not any(libs.glob("kafka_2.13-*.jar")):
        where = f"{libs} (from PLANTKG_KAFKA_HOME)" if "PLANTKG_KAFKA_HOME" in os.environ else str(libs)
        raise KafkaMissingError(f"Kafka {version} broker jars (kafka_2.13-*.jar)", where)
    return KafkaParts(
        version=version,
        home=home,
        libs=libs,
        log4j_config=_first_file(home / "log4j.properties", home / "config" / "log4j.properties"),
        tools_log4j_config=_first_file(
            home / "tools-log4j.properties", home / "config" / "tools-log4j.properties"
        ),
    )


def _first_file(*candidates: Path) -> Path | None:
    return next((c for c in candidates if c.is_file()), None)
