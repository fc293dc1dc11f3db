"""Files of the data directory: atomic writes, safe names, one lock for read-modify-write.

A file is written whole or not at all (a temporary file in the same folder, fsync, rename,
fsync of the folder): a kill -9 of the fleet manager never leaves half a Turtle file that would
make the next load of the plant fail. Names come from ``manufacturer--serial``; anything outside
``A-Z a-z 0-9 _ . : -`` in the manufacturer is percent-encoded (a serial never has such
characters: it was checked on receipt).
"""

from __future__ import annotations

import fcntl
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from engine.whole_file import fsync_dir, write_whole

_SAFE = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789_.:-")


def stem(manufacturer: str, serial: str) -> str:
    """``<manufacturer>--<serial>`` made safe for a file name (never hidden, never a path)."""
    def enc(text: str) -> str:
        out = "".join(c if c in _SAFE else "".join(f"%{b:02X}" for b in c.encode()) for c in text)
        return "%2E" + out[1:] if out.startswith(".") else out
    return f"{enc(manufacturer) or '_'}--{enc(serial)}"


def atomic_write(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` so that readers see the old file or the new one, never a part
    (durable: fsynced with its folder)."""
    write_whole(path, text, mode=0o644, durable=True)


def move(src: Path, dst: Path) -> None:
    """Rename ``src`` to ``dst`` (same file system), both folders synced."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    os.replace(src, dst)
    fsync_dir(dst.parent)
    fsync_dir(src.parent)


@contextmanager
def locked(data_dir: Path) -> Iterator[None]:
    """An exclusive lock on the data directory (the manager and ``plantkg fleet`` commands)."""
    data_dir.mkdir(parents=True, exist_ok=True)
    with open(data_dir / ".lock", "a+") as fh:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)
