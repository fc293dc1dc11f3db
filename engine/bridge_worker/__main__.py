"""``python -m engine.bridge_worker <worker.json>``: run one bridge worker until SIGTERM/SIGINT.

``worker.json`` says which kind: ``"mechanism": "mqtt-ngsi"`` runs the MQTT <-> NGSI worker
(:mod:`engine.bridge_worker.ngsi_worker`), anything else the MQTT <-> Kafka one.
``python -m engine.bridge_worker --remove <worker.json>`` (NGSI only) deletes the bridge's
subscriptions on the context broker and exits: the agent runs it when the bridge is deleted.

Exit codes: 0 after a clean stop, 2 for a config that cannot be used (one line on stderr naming
the field), 1 when ``--remove`` could not reach the context broker. Logs go to stderr; the
carrying agent redirects them to the bridge's log file.
"""

from __future__ import annotations

import logging
import gc
import signal
import sys
from pathlib import Path

from engine.bridge_worker.config import WorkerConfig
from engine.bridge_worker.ngsi_config import NgsiWorkerConfig, is_ngsi_config
from engine.errors import ConfigValueError

EXIT_OK = 0
EXIT_FAILED = 1
EXIT_BAD_CONFIG = 2
USAGE = "usage: python -m engine.bridge_worker [--remove] <worker.json>"


def load(path_arg: str) -> WorkerConfig | NgsiWorkerConfig:
    try:
        text = Path(path_arg).read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigValueError("worker.json", path_arg, f"cannot be read: {exc.strerror}") from None
    if is_ngsi_config(text):
        return NgsiWorkerConfig.from_json(text)
    return WorkerConfig.from_json(text)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    remove = bool(args) and args[0] == "--remove"
    if remove:
        args = args[1:]
    if len(args) != 1 or args[0].startswith("--"):
        print(USAGE, file=sys.stderr)
        return EXIT_BAD_CONFIG
    try:
        cfg = load(args[0])
    except ConfigValueError as exc:
        print(f"bridge worker: {args[0]}: {exc.message}", file=sys.stderr)
        return EXIT_BAD_CONFIG
    logging.basicConfig(stream=sys.stderr, level=logging.INFO,
                        format=f"%(asctime)s bridge {cfg.bridge_id} %(levelname)s %(name)s: %(message)s")
    if remove:
        return _remove(cfg)
    if isinstance(cfg, NgsiWorkerConfig):
        from engine.bridge_worker.ngsi_worker import NgsiWorker  # noqa: PLC0415 - no Kafka client needed
        worker: object = NgsiWorker(cfg)
    else:
        from engine.bridge_worker.worker import Worker  # noqa: PLC0415 - loads confluent_kafka
        worker = Worker(cfg)
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: worker.stopping.set())  # type: ignore[attr-defined]
    # What exists now (modules, clients, configuration) lives as long as the process: frozen, it is
    # out of the collector's reach, and a full collection scans only what forwarding makes (a full
    # collection stalls every message behind it). benchmarks/bench_bridge's paced p99 at 10k msg/s,
    # MQTT -> Kafka: 93.3 ms at 73a6302, 18.0 ms with this (bf00eb2), 61.9 ms at e5fb3a0: the paced
    # tail moves between runs on two shared cores, so these runs do not show what this is worth.
    gc.freeze()
    worker.run()  # type: ignore[attr-defined]
    return EXIT_OK


def _remove(cfg: WorkerConfig | NgsiWorkerConfig) -> int:
    if not isinstance(cfg, NgsiWorkerConfig):
        print("bridge worker: --remove is for mqtt-ngsi bridges (a Kafka bridge leaves nothing "
              "on its remote)", file=sys.stderr)
        return EXIT_BAD_CONFIG
    from engine.bridge_worker.ngsi_client import NgsiError  # noqa: PLC0415
    from engine.bridge_worker.ngsi_worker import remove_subscriptions  # noqa: PLC0415
    try:
        removed = remove_subscriptions(cfg)
    except NgsiError as exc:
        print(f"bridge worker: cannot remove the subscriptions of {cfg.bridge_id}: {exc.text}",
              file=sys.stderr)
        return EXIT_FAILED
    logging.getLogger("plantkg.bridge").info("removed %d subscriptions from %s", removed, cfg.ngsi_url)
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
