#!/usr/bin/env bash
# Install the real parts plantkg runs against, idempotently; `make setup` calls this.
#   1. Debian packages: mosquitto (the system service is stopped and disabled: tests and agents
#      spawn their own brokers), a Java runtime and Maven, each only if its command is missing;
#      rabbitmq-server for the RabbitMQ plugin (its system service stopped and disabled too).
#   2. Python: .venv with plantkg installed editable plus the test extra, redone only when
#      pyproject.toml changed (stamp: .venv/.plantkg-pyproject.sha256); then the broker-type plugin
#      plugins/plantkg-rabbitmq, editable, redone only when its pyproject.toml changed; then the
#      project's bytecode (compileall: only what changed).
#   3. Kafka: broker jars resolved from Maven Central by third_party/kafka/pom.xml into
#      .plantkg/kafka/<version>/libs, redone only when the pom changed (stamp beside libs/).
#   4. The Go load generator tools/loadgen (benchmarks' MQTT/Kafka clients) built into
#      .plantkg/loadgen/loadgen, redone only when its sources changed (stamp beside it); skipped
#      with a message when `go` is absent (the benchmarks that need it then refuse, naming it).
# A second run installs nothing and takes about a second.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"

PYTHON="${PYTHON:-python3}"
VENV="$ROOT/.venv"
POM="$ROOT/third_party/kafka/pom.xml"

say() { printf 'setup: %s\n' "$*"; }
die() { printf 'setup: error: %s\n' "$*" >&2; exit 1; }
sha() { sha256sum "$@" | cut -d' ' -f1; }

# Run a command with its output in a log file; show the log only if the command fails.
LOG_DIR="$ROOT/.plantkg/setup-logs"
quietly() { # name command...
    local log="$LOG_DIR/$1.log"
    shift
    mkdir -p "$LOG_DIR"
    if ! "$@" >"$log" 2>&1; then
        tail -n 60 "$log" >&2
        die "'$*' failed; full log: ${log#"$ROOT"/}"
    fi
}

# --- 1. Debian packages -------------------------------------------------------------------------

have() { command -v "$1" >/dev/null 2>&1; }
# mosquitto lives in /usr/sbin, which a non-root PATH often lacks.
have_mosquitto() { have mosquitto || [ -x /usr/sbin/mosquitto ]; }

# Root for apt: ourselves, else sudo (decided before running anything, so a refusal is visible).
SUDO=()
need_root() {
    [ "$(id -u)" -eq 0 ] && return 0
    have sudo || die "installing ${APT_WANTED[*]} needs root and sudo is missing; install them as root, then rerun"
    SUDO=(sudo)
}
as_root() { "${SUDO[@]}" "$@"; }

# The Debian package starts and enables a system-wide mosquitto on port 1883; we spawn our own.
disable_system_mosquitto() {
    if [ -d /run/systemd/system ] && have systemctl; then
        as_root systemctl disable --now mosquitto.service >/dev/null 2>&1 || true
    else
        if [ -x /etc/init.d/mosquitto ]; then
            as_root /etc/init.d/mosquitto stop >/dev/null 2>&1 || true
        fi
        if have update-rc.d; then
            as_root update-rc.d mosquitto disable >/dev/null 2>&1 || true
        fi
    fi
}

# Other Debian services we install but never use system-wide (our agents spawn their own nodes).
disable_system_service() { # name
    if [ -d /run/systemd/system ] && have systemctl; then
        as_root systemctl disable --now "$1.service" >/dev/null 2>&1 || true
    else
        if [ -x "/etc/init.d/$1" ]; then
            as_root "/etc/init.d/$1" stop >/dev/null 2>&1 || true
        fi
        if have update-rc.d; then
            as_root update-rc.d "$1" disable >/dev/null 2>&1 || true
        fi
    fi
}

APT_WANTED=()
have_mosquitto || APT_WANTED+=(mosquitto)
# mosquitto_pub/mosquitto_sub: independent clients of the broker-users tests (issue 13), and the
# bridge benchmarks' C load generator and receiver (benchmarks/bridge_load.py, issue 16).
have mosquitto_pub || APT_WANTED+=(mosquitto-clients)
# kcat: the independent Kafka client of the Kafka users/ACL tests (issue 13).
have kcat || APT_WANTED+=(kcat)
# RabbitMQ for plugins/plantkg-rabbitmq; the plugin runs the real script, not /usr/sbin's wrapper.
[ -x /usr/lib/rabbitmq/bin/rabbitmq-server ] || APT_WANTED+=(rabbitmq-server)
have java || APT_WANTED+=(default-jre-headless)
have mvn || APT_WANTED+=(maven)
# Debian's Chromium for the dashboard's browser tests (Playwright drives it; no browser download).
have chromium || APT_WANTED+=(chromium)
# iproute2 (ip, tc) for the deploy benchmark's emulated remote machine (network namespace + netem).
have_iproute() { { have ip || [ -x /usr/sbin/ip ]; } && { have tc || [ -x /usr/sbin/tc ]; }; }
have_iproute || APT_WANTED+=(iproute2)

if [ "${#APT_WANTED[@]}" -gt 0 ]; then
    have apt-get || die "missing ${APT_WANTED[*]} and no apt-get here; install them with your package manager"
    need_root
    say "apt: installing ${APT_WANTED[*]}"
    quietly apt-update as_root apt-get update
    quietly apt-install as_root env DEBIAN_FRONTEND=noninteractive \
        apt-get install -y --no-install-recommends "${APT_WANTED[@]}"
    if [[ " ${APT_WANTED[*]} " == *" mosquitto "* ]]; then
        say "apt: stopping and disabling the system mosquitto service (plantkg spawns its own)"
        disable_system_mosquitto
    fi
    if [[ " ${APT_WANTED[*]} " == *" rabbitmq-server "* ]]; then
        say "apt: stopping and disabling the system rabbitmq-server service (plantkg spawns its own)"
        disable_system_service rabbitmq-server
        # The package's own scripts start Erlang's port mapper as a daemon (port 4369), which
        # outlives the service; our nodes run their own. -kill stops it only if no node uses it.
        if have epmd; then
            as_root epmd -kill >/dev/null 2>&1 || true
        fi
    fi
fi

# --- 2. Python environment ----------------------------------------------------------------------

if [ ! -x "$VENV/bin/python" ]; then
    have "$PYTHON" || die "$PYTHON not found; install Python 3.11 or newer"
    say "python: creating .venv with $("$PYTHON" --version 2>&1)"
    "$PYTHON" -m venv "$VENV"
fi

PY_STAMP="$VENV/.plantkg-pyproject.sha256"
PY_HASH="$(sha pyproject.toml)"
if [ "$(cat "$PY_STAMP" 2>/dev/null || true)" != "$PY_HASH" ]; then
    say "python: pip install -e '.[test]' (pyproject.toml changed since the last install)"
    quietly pip-install "$VENV/bin/python" -m pip install --disable-pip-version-check -e '.[test]'
    printf '%s\n' "$PY_HASH" >"$PY_STAMP"
fi

# Broker types as plugins: a package of their own each, installed after plantkg (their dependency).
for plugin in plugins/plantkg-rabbitmq; do
    PLUGIN_STAMP="$VENV/.$(basename "$plugin")-pyproject.sha256"
    PLUGIN_HASH="$(sha "$plugin/pyproject.toml")"
    if [ "$(cat "$PLUGIN_STAMP" 2>/dev/null || true)" != "$PLUGIN_HASH" ] \
        || ! "$VENV/bin/python" -c 'import importlib.metadata as m, sys; m.version(sys.argv[1])' \
            "$(basename "$plugin")" >/dev/null 2>&1; then
        say "python: pip install -e $plugin (new, uninstalled or its pyproject.toml changed)"
        quietly "pip-install-$(basename "$plugin")" "$VENV/bin/python" -m pip install \
            --disable-pip-version-check -e "$plugin"
        printf '%s\n' "$PLUGIN_HASH" >"$PLUGIN_STAMP"
    fi
done

# The project's own bytecode, compiled now: where PYTHONDONTWRITEBYTECODE is set (as on CI
# machines), Python would otherwise compile every module of ours in memory at each start of a
# command (~0.1 s of `plantkg apply`). Only changed sources are compiled again; a stale .pyc is
# never used (Python checks the source's mtime).
"$VENV/bin/python" -m compileall -q -j 0 engine kg fleet plugins benchmarks >/dev/null \
    || say "python: compiling the bytecode failed (commands start slower; nothing else changes)"

# --- 3. Kafka jars ------------------------------------------------------------------------------

KAFKA_VERSION="$(sed -n 's:.*<kafka.version>\(.*\)</kafka.version>.*:\1:p' "$POM")"
[ -n "$KAFKA_VERSION" ] || die "no <kafka.version> in $POM"
KAFKA_HOME="$ROOT/.plantkg/kafka/$KAFKA_VERSION"
KAFKA_STAMP="$KAFKA_HOME/.pom.sha256"
POM_HASH="$(sha "$POM")"

if [ "$(cat "$KAFKA_STAMP" 2>/dev/null || true)" != "$POM_HASH" ] || [ ! -d "$KAFKA_HOME/libs" ]; then
    say "kafka: resolving Apache Kafka $KAFKA_VERSION jars from Maven Central into ${KAFKA_HOME#"$ROOT"/}/libs"
    mkdir -p "$KAFKA_HOME"
    rm -rf "$KAFKA_HOME/libs.partial"
    # Into a scratch folder first, so an interrupted resolve never leaves a half libs/ behind.
    quietly mvn mvn -B -f "$POM" dependency:copy-dependencies \
        -DincludeScope=runtime -DoutputDirectory="$KAFKA_HOME/libs.partial"
    rm -rf "$KAFKA_HOME/libs"
    mv "$KAFKA_HOME/libs.partial" "$KAFKA_HOME/libs"
    printf '%s\n' "$POM_HASH" >"$KAFKA_STAMP"
fi

# log4j 1.2 configs (Kafka 3.x binds slf4j to reload4j): the broker logs INFO to stdout, which the
# engine sends to the broker's log file; tools (StorageTool) log WARN to stderr only.
write_if_changed() { # file content
    if [ "$(cat "$1" 2>/dev/null || true)" != "$2" ]; then
        say "kafka: writing ${1#"$ROOT"/}"
        printf '%s\n' "$2" >"$1"
    fi
}
write_if_changed "$KAFKA_HOME/log4j.properties" "log4j.rootLogger=INFO, stdout
log4j.appender.stdout=org.apache.log4j.ConsoleAppender
log4j.appender.stdout.layout=org.apache.log4j.PatternLayout
log4j.appender.stdout.layout.ConversionPattern=[%d] %p %m (%c)%n"
write_if_changed "$KAFKA_HOME/tools-log4j.properties" "log4j.rootLogger=WARN, stderr
log4j.appender.stderr=org.apache.log4j.ConsoleAppender
log4j.appender.stderr.Target=System.err
log4j.appender.stderr.layout=org.apache.log4j.PatternLayout
log4j.appender.stderr.layout.ConversionPattern=[%d] %p %m (%c)%n"

# --- 4. Go load generator ----------------------------------------------------------------------

LOADGEN_SRC="$ROOT/tools/loadgen"
LOADGEN_DIR="$ROOT/.plantkg/loadgen"
GO="$(command -v go || { [ -x /usr/local/go/bin/go ] && echo /usr/local/go/bin/go; } || true)"
LOADGEN_NOTE="loadgen (go absent: benchmarks using it will refuse)"
if [ -n "$GO" ]; then
    LOADGEN_HASH="$(cd "$LOADGEN_SRC" && cat go.mod go.sum ./*.go | sha256sum | cut -d' ' -f1)"
    if [ "$(cat "$LOADGEN_DIR/.sources.sha256" 2>/dev/null || true)" != "$LOADGEN_HASH" ] \
        || [ ! -x "$LOADGEN_DIR/loadgen" ]; then
        say "go: building tools/loadgen into ${LOADGEN_DIR#"$ROOT"/}/loadgen (its sources changed)"
        mkdir -p "$LOADGEN_DIR"
        (cd "$LOADGEN_SRC" && quietly loadgen "$GO" build -trimpath -o "$LOADGEN_DIR/loadgen.partial" .)
        mv "$LOADGEN_DIR/loadgen.partial" "$LOADGEN_DIR/loadgen"
        printf '%s\n' "$LOADGEN_HASH" >"$LOADGEN_DIR/.sources.sha256"
    fi
    LOADGEN_NOTE="loadgen ($("$GO" version | cut -d' ' -f3))"
else
    say "go: not found; skipping tools/loadgen (install Go >= 1.22 from https://go.dev/dl and rerun to run bench_security)"
fi

say "ready: mosquitto $(command -v mosquitto || echo /usr/sbin/mosquitto), java $(command -v java), kafka $KAFKA_VERSION, .venv, $LOADGEN_NOTE"
