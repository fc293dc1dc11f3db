"""Run the LoTLan authors' lotlan-scheduler on files; print one JSON verdict per file.

Used by test_lotlan_differential.py as a SUBPROCESS whose working directory is a temporary folder:
lotlan-scheduler writes files (Petri-net drawings, a sqlite database) into the working directory
and prints its errors on stdout, so it runs apart from the test process. Its public entry point is
``LotlanScheduler(text)``: it raises ValueError(list of messages) for a program it refuses. Any
other exception is reported as "crashed" (e.g. an unquoted number in an instance).

    python lotlan_scheduler_run.py FILE... > verdicts.jsonl
"""

from __future__ import annotations

import contextlib
import io
import json
import sys


def verdict(text: str) -> dict[str, object]:
    from lotlan_scheduler.scheduler import LotlanScheduler

    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        try:
            LotlanScheduler(text)
        except ValueError as error:
            messages = error.args[0] if error.args and isinstance(error.args[0], list) else [str(error)]
            return {"verdict": "refused", "errors": [str(m) for m in messages]}
        except Exception as error:  # noqa: BLE001 - any crash of the other implementation is data
            return {"verdict": "crashed", "errors": [f"{type(error).__name__}: {error}"]}
    return {"verdict": "accepted", "errors": []}


def main(paths: list[str]) -> int:
    for path in paths:
        with open(path, encoding="utf-8") as handle:
            result = verdict(handle.read())
        print(json.dumps({"file": path, **result}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
