"""``python -m fleet.lotlan check FILE...``: check LoTLan files, print ``file:line:col: message``.

Exit status 0 when every file is a usable program, 1 when any has a problem (each problem is a
line on stdout), 2 when the command line itself is wrong (argparse). A file that cannot be read
is a problem of that file, not a crash.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from fleet.lotlan import analyse
from fleet.lotlan.errors import Diagnostic


def check_file(path: Path) -> tuple[Diagnostic, ...]:
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        reason = error.strerror if isinstance(error, OSError) and error.strerror else str(error)
        return (Diagnostic(str(path), 1, 1, f"cannot read the file: {reason}"),)
    return analyse(text, str(path))[1]


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m fleet.lotlan",
                                     description="Check LoTLan (Logistic Task Language) files.")
    commands = parser.add_subparsers(dest="command", required=True)
    check = commands.add_parser("check", help="check files; print file:line:col: message per problem")
    check.add_argument("files", nargs="+", type=Path, metavar="FILE")
    args = parser.parse_args(argv)
    failed = 0
    for path in args.files:
        diagnostics = check_file(path)
        for diagnostic in diagnostics:
            print(diagnostic)
        failed += bool(diagnostics)
    if failed:
        print(f"{failed} of {len(args.files)} file(s) refused", file=sys.stderr)
        return 1
    return 0
