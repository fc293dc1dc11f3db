"""``python -m engine.bridge_worker <worker.json>``: run one bridge worker until SIGTERM/SIGINT.

Exit codes: 0 after a clean stop, 2 for a config that cannot be used (one line on stderr naming
the field). Logs go to stderr; the carrying agent redirects them to the bridge's log file.
"""

from __future__ import annotations

import logging
import signal
import sys
from pathlib import Path

from engine.bridge_worker.config import WorkerConfig
from engine.bridge_worker.worker import Worker
from engine.errors import ConfigValueError

EXIT_OK = 0
EXIT_BAD_CONFIG = 2


def load(path_arg: str) -> WorkerConfig:
    try:
        text = Path(path_arg).read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigValueError("worker.json", path_arg, f"cannot be read: {exc.strerror}") from None
    return WorkerConfig.from_json(text)


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m engine.bridge_worker <worker.json>", file=sys.stderr)
        return EXIT_BAD_CONFIG
    try:
        cfg = load(args[0])
    except ConfigValueError as exc:
        print(f"bridge worker: {args[0]}: {exc.message}", file=sys.stderr)
        return EXIT_BAD_CONFIG
    logging.basicConfig(stream=sys.stderr, level=logging.INFO,
                        format=f"%(asctime)s bridge {cfg.bridge_id} %(levelname)s %(name)s: %(message)s")
    worker = Worker(cfg)
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: worker.stopping.set())
    worker.run()
    return EXIT_OK


if __name__ == "__main__":
    sys.exit(main())
