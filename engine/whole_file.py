"""Files that appear whole or not at all, for every writer of plantkg.

A reader of a state file, a key or a token must see the old content or the new one, never a
part, and two writers (processes or threads) must never write the same file aside. Both helpers
write aside under a name unique to the call (``tempfile.mkstemp``: not merely this process's pid,
which threads share — the cause of two threads creating two different principal keys), then:

- ``write_whole`` renames it over the target (the last writer wins);
- ``create_once`` hard-links it to the target, which fails if the target exists (the first
  writer wins and every other reads what it wrote).

``durable=True`` also fsyncs the file and its folder, so the write survives a power cut or a
kill -9 of the machine's kernel, not just of the writer.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path


def _aside(path: Path, data: bytes, mode: int, durable: bool, make_folder: bool) -> Path:
    """``data`` written to a new file beside ``path`` (exactly ``mode``, whatever the umask)."""
    try:
        fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".new", dir=path.parent)
    except FileNotFoundError:
        if not make_folder:
            raise
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".new", dir=path.parent)
    aside = Path(name)
    try:
        with os.fdopen(fd, "wb") as fh:
            os.fchmod(fh.fileno(), mode)
            fh.write(data)
            if durable:
                fh.flush()
                os.fsync(fh.fileno())
    except BaseException:
        aside.unlink(missing_ok=True)
        raise
    return aside


def _bytes(data: bytes | str) -> bytes:
    return data.encode("utf-8") if isinstance(data, str) else data


def fsync_dir(folder: Path) -> None:
    """Make a rename or link in ``folder`` durable."""
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def write_whole(path: Path, data: bytes | str, mode: int = 0o644, durable: bool = False) -> None:
    """Replace ``path`` with ``data`` (str as UTF-8) whole; its folder is made if missing (the
    folder is tried first: a broker start writes several files, and each saved syscall counts
    when 100 start at once)."""
    aside = _aside(path, _bytes(data), mode, durable, make_folder=True)
    try:
        os.replace(aside, path)
    except BaseException:
        aside.unlink(missing_ok=True)
        raise
    if durable:
        fsync_dir(path.parent)


def create_once(path: Path, data: bytes | str, mode: int = 0o600, durable: bool = False) -> bool:
    """Create ``path`` with ``data`` whole unless it exists. True if this call created it; False
    if it existed (or another writer created it meanwhile): then read what is there. The folder
    must exist (FileNotFoundError otherwise)."""
    if path.exists():
        return False
    aside = _aside(path, _bytes(data), mode, durable, make_folder=False)
    try:
        os.link(aside, path)
    except FileExistsError:
        return False
    finally:
        aside.unlink(missing_ok=True)
    if durable:
        fsync_dir(path.parent)
    return True
