"""The context store's write-ahead log: one append-only file of framed records, so a write can
be acknowledged after ONE ``os.write`` and reach Oxigraph later, in batches.

- A record is ``length (u32) | crc32 (u32) | seq (u64) | payload``, little-endian; the CRC covers
  the sequence number and the payload. Records are written with a single ``os.write`` on an
  ``O_APPEND`` descriptor: once it returns the record is in the operating system's page cache and
  survives kill -9 of the process. A power loss or kernel crash needs ``fsync=True`` (one
  ``fdatasync`` per record).
- :func:`read_records` reads a log back. A torn last record (the process killed mid-write: short
  header, short payload or a wrong CRC) ends the log: it was never acknowledged, so it is dropped.
  A record out of sequence ends it as well.
- :meth:`WriteAheadLog.rotate` renames the live file to ``<name>.old`` and starts an empty one;
  the owner deletes the old file once every record in it is applied (:meth:`discard_old`).
"""

from __future__ import annotations

import logging
import os
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

from engine.whole_file import fsync_dir

log = logging.getLogger(__name__)
HEADER = struct.Struct("<IIQ")
MAX_RECORD = 1 << 30


@dataclass(frozen=True)
class Record:
    seq: int
    payload: bytes


def encode(seq: int, payload: bytes) -> bytes:
    crc = zlib.crc32(payload, zlib.crc32(seq.to_bytes(8, "little")))
    return HEADER.pack(len(payload), crc, seq) + payload


def read_records(path: Path, after: int | None = None) -> tuple[list[Record], bool]:
    """The whole records of ``path`` in order and whether a torn or broken tail was dropped.
    ``after``: the sequence number the first record must follow (None: any)."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        return [], False
    records: list[Record] = []
    pos, expected = 0, None if after is None else after + 1
    while pos < len(data):
        if pos + HEADER.size > len(data):
            return records, True
        length, crc, seq = HEADER.unpack_from(data, pos)
        end = pos + HEADER.size + length
        if length > MAX_RECORD or end > len(data):
            return records, True
        payload = data[pos + HEADER.size:end]
        if zlib.crc32(payload, zlib.crc32(seq.to_bytes(8, "little"))) != crc:
            return records, True
        if expected is not None and seq != expected:
            log.warning("%s: record %d follows %d, dropping it and the rest", path, seq, expected - 1)
            return records, True
        records.append(Record(seq, payload))
        expected = seq + 1
        pos = end
    return records, False


class WriteAheadLog:
    """The live log file ``path`` (created empty; an existing one must have been replayed and is
    truncated, unless ``truncate`` is False: then records are appended to it, numbered from
    ``next_seq``). Not thread-safe: the store appends under its write lock."""

    def __init__(self, path: Path, *, fsync: bool = False, next_seq: int = 1,
                 truncate: bool = True) -> None:
        self.path = path
        self.old_path = path.with_name(path.name + ".old")
        self.fsync = fsync
        self.next_seq = next_seq
        self.size = 0
        self._truncate = truncate
        self._fd = self._open()

    def _open(self) -> int:
        flags = os.O_WRONLY | os.O_CREAT | os.O_APPEND | (os.O_TRUNC if self._truncate else 0)
        fd = os.open(self.path, flags, 0o600)
        if self.fsync:
            fsync_dir(self.path.parent)
        return fd

    def append(self, payload: bytes) -> int:
        """Write one record; its sequence number once it is in the file."""
        seq = self.next_seq
        frame = encode(seq, payload)
        written = os.write(self._fd, frame)
        if written != len(frame):  # a full disk: undo the partial frame, refuse the write
            os.ftruncate(self._fd, self.size)
            raise OSError(f"write-ahead log {self.path}: wrote {written} of {len(frame)} bytes "
                          "(disk full?)")
        if self.fsync:
            os.fdatasync(self._fd)
        self.next_seq = seq + 1
        self.size += written
        return seq

    def rotate(self) -> None:
        """The live file becomes ``<name>.old``; new records go to a fresh file."""
        os.close(self._fd)
        os.replace(self.path, self.old_path)
        self._truncate = True
        self._fd = self._open()
        self.size = 0

    def discard_old(self) -> None:
        self.old_path.unlink(missing_ok=True)

    def close(self, *, remove: bool = False) -> None:
        if self._fd >= 0:
            os.close(self._fd)
            self._fd = -1
        if remove:
            self.discard_old()
            self.path.unlink(missing_ok=True)


__all__ = ["Record", "WriteAheadLog", "encode", "read_records"]
