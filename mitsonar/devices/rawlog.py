"""The raw byte log of a serial head: `RawLogWriter` writes it, `read_log` reads it back.

Format (little-endian)::

    file header   8s  magic b"MSNRLOG1"
                  H   format version (1)
                  H   reserved (0)
                  d   start time, Unix seconds
                  I   n, length of the metadata
                  n   metadata, UTF-8 JSON: port, baudrate, sound_speed, nibble_order,
                      settings (HeadSettings fields), pose (4x4), revisit, max_turns, passive;
                      head: "ping360" for a Blue Robotics Ping360 (then settings holds
                      Ping360Settings fields), absent for a SeaNet head
    records       d   time since the start, s
                  B   record type: 0 bytes received from the head, 1 bytes sent to it,
                      2 head pose (16 float64, row-major 4x4)
                  I   m, payload length
                  m   payload

A record cut short at the end (recorder killed) is not read; neither is a damaged stretch,
after which reading picks up where whole records follow each other again. Both are reported
(`read_log`: ``meta["skipped"]`` and a `LogDamageWarning`), as are bytes that
`mitsonar.devices.recording.replay` finds to be no SeaNet packet (or ping-protocol message). Nothing
here knows either protocol.
"""
from __future__ import annotations

import json
import math
import os
import struct
import time
import warnings
from pathlib import Path

import numpy as np

from mitsonar._moved import renamed_keyword

__all__ = ["RawLogWriter", "read_log", "part_name", "LOG_MAGIC", "LogDamageWarning", "RX", "TX", "POSE"]

LOG_MAGIC = b"MSNRLOG1"
RX, TX, POSE = 0, 1, 2
_LOG_HEADER = struct.Struct("<8sHHdI")
_LOG_RECORD = struct.Struct("<dBI")


class LogDamageWarning(UserWarning):
    """`read_log` or `replay` skipped damaged bytes of a raw log (the message says where)."""


def part_name(path) -> Path:
    """The temporary name an output is written under before it is renamed to ``path``.

    Same folder (so the rename is atomic on one file system), hidden, marked with the process
    id, same suffix (writers that choose the format by suffix still see it).
    """
    path = Path(path)
    return path.with_name(f".{path.stem}.part{os.getpid()}{path.suffix}")


class RawLogWriter:
    """Writes the raw-log format of this module (see the module docstring).

    Parameters
    ----------
    =========  ==============================================================
    path       file to create (overwritten)
    meta       JSON-serialisable dict stored in the header
    temporary  write under `part_name` (path) and rename to ``path`` on `close`;
               `discard` removes it instead (default False: write ``path`` directly)
    =========  ==============================================================
    """

    def __init__(self, path, meta: dict | None = None, *, temporary: bool = False):
        self.path = Path(path)
        self._file_path = part_name(self.path) if temporary else self.path
        self._t0 = time.time()
        self._m0 = time.monotonic()
        blob = json.dumps(meta or {}, sort_keys=True).encode("utf-8")
        try:
            self._f = open(self._file_path, "wb")
        except OSError as e:       # its text would name the temporary file
            raise type(e)(f"{self.path}: cannot be written ({e.strerror or e})") from None
        self._f.write(_LOG_HEADER.pack(LOG_MAGIC, 1, 0, self._t0, len(blob)) + blob)
        self.bytes_rx = 0
        self.bytes_tx = 0

    @renamed_keyword("kind", "record_type", "RawLogWriter.write(kind=...)")
    def write(self, record_type: int, data: bytes) -> None:
        """Append one record of ``record_type`` (`RX`, `TX` or `POSE`; the old keyword ``kind``
        works until 0.4.0 with a DeprecationWarning) holding ``data``."""
        if record_type not in (RX, TX, POSE):
            # read_log finds its way through damage by what the writer can write.
            raise ValueError(f"RawLogWriter.write: record_type must be RX (0), TX (1) or POSE (2), "
                             f"got {record_type!r}")
        if self._f is None or not data:
            return
        t = time.monotonic() - self._m0
        self._f.write(_LOG_RECORD.pack(t, record_type, len(data)) + bytes(data))
        if record_type == RX:
            self.bytes_rx += len(data)
        elif record_type == TX:
            self.bytes_tx += len(data)

    def rx(self, data: bytes) -> None:
        self.write(RX, data)

    def tx(self, data: bytes) -> None:
        self.write(TX, data)

    def pose(self, T) -> None:
        self.write(POSE, np.asarray(T, dtype="<f8").reshape(16).tobytes())

    def close(self) -> None:
        """Close the file (renamed to ``path`` if it was written under a temporary name)."""
        if self._f is not None:
            self._f.close()
            self._f = None
            if self._file_path != self.path:
                os.replace(self._file_path, self.path)

    def discard(self) -> None:
        """Close and delete what was written (``path`` is left as it was if ``temporary``)."""
        if self._f is not None:
            self._f.close()
            self._f = None
        try:
            os.remove(self._file_path)
        except FileNotFoundError:
            pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _record_at(raw: bytes, pos: int, t_prev: float, strict: bool = False):
    """``(t, record_type, m)`` if a record header that `RawLogWriter` could have written starts at
    ``pos`` (``m`` may run past the end of the file), else None. ``strict`` for offsets not
    known to start a record (after damage), where bytes of the serial stream can look like a
    header: a time stamp within an hour of the last good record's."""
    if pos + _LOG_RECORD.size > len(raw):
        return None
    t, record_type, m = _LOG_RECORD.unpack_from(raw, pos)
    # The writer stamps records with a monotonic clock, never writes an empty record, and a
    # pose is 16 float64. A little slack on the time: the pose may be set from another thread.
    if record_type not in (RX, TX, POSE) or m == 0 or (record_type == POSE and m != 128):
        return None
    if not (math.isfinite(t) and t >= 0.0 and t >= t_prev - 1.0):
        return None
    if strict and not 1e-9 <= t <= t_prev + 3600.0:
        return None
    return t, record_type, m


def _chain_at(raw: bytes, pos: int, t_prev: float, depth: int, strict: bool = False) -> bool:
    """Do ``depth`` plausible records follow each other from ``pos`` (fewer where the file ends)?

    A record cut short by the end of the file counts after a whole one, or first unless
    ``strict``: else any header-like bytes with a large length would do.
    """
    for i in range(depth):
        if pos > len(raw) - _LOG_RECORD.size:
            # The file ends here, exactly or inside a header.
            return i > 0 or pos == len(raw) or not strict
        rec = _record_at(raw, pos, t_prev, strict)
        if rec is None:
            return False
        t_prev, pos = rec[0], pos + _LOG_RECORD.size + rec[2]
        if pos > len(raw):
            return i > 0 or not strict
    return True


def _resync(raw: bytes, pos: int, t_prev: float) -> int | None:
    """The first offset from ``pos`` where whole records start again, or None."""
    b = np.frombuffer(raw, dtype=np.uint8)
    last = len(raw) - _LOG_RECORD.size      # last offset a header fits at
    block = 1 << 16
    for lo in range(pos, last + 1, block):
        hi = min(lo + block, last + 1)
        # A record-type byte and a nonzero length rule out most offsets before the slower checks.
        ok = (b[lo + 8:hi + 8] <= POSE) & ((b[lo + 9:hi + 9] | b[lo + 10:hi + 10]
                                            | b[lo + 11:hi + 11] | b[lo + 12:hi + 12]) != 0)
        for q in np.flatnonzero(ok) + lo:
            if _chain_at(raw, int(q), t_prev, 3, strict=True):
                return int(q)
    return None


def read_log(path) -> tuple[dict, list[tuple[float, int, bytes]]]:
    """``(meta, records)`` of a raw log; ``meta["start_time"]`` holds the header's start time.

    Raises ValueError with a one-line reason if the file is not such a log. A damaged stretch
    (a record header that the writer cannot have written) is skipped up to the next offset
    where whole records follow each other again, so what comes after the damage is kept;
    ``meta["skipped"]`` then lists ``[offset, n_bytes, reason]`` of every stretch not read
    (reason ``"damaged"``, or ``"record cut short at the end"``; ``"overlap"``: a record
    whose damaged header begins ``n_bytes`` before the end of the one before it), and a
    `LogDamageWarning` says so in one line.

    Without a checksum, damage that leaves a record length pointing exactly at a later record
    cannot be seen here: that record's payload then holds the damage (for the SeaNet parser
    of `replay` to find) and the records in between are lost.
    """
    raw = Path(path).read_bytes()
    if not raw:
        raise ValueError(f"{path}: empty file, not a mitsonar raw log")
    if raw[:len(LOG_MAGIC)] != LOG_MAGIC:
        raise ValueError(f"{path}: not a mitsonar raw log (missing {LOG_MAGIC!r} header)")
    if len(raw) < _LOG_HEADER.size:
        raise ValueError(f"{path}: truncated log: {len(raw)} bytes, less than the "
                         f"{_LOG_HEADER.size}-byte file header; no records")
    magic, version, _, t0, n = _LOG_HEADER.unpack_from(raw, 0)
    if version != 1:
        raise ValueError(f"{path}: raw log format version {version} is not supported (only 1)")
    pos = _LOG_HEADER.size
    if pos + n > len(raw):
        raise ValueError(f"{path}: truncated log: the metadata at bytes {pos}..{pos + n} ends "
                         f"after the file ({len(raw)} bytes)")
    try:
        meta = json.loads(raw[pos:pos + n].decode("utf-8")) if n else {}
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: corrupt log metadata at bytes {pos}..{pos + n} ({e})") from None
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: corrupt log metadata (not an object)")
    meta["start_time"] = t0
    pos += n
    records = []
    skipped = []
    t_prev = 0.0
    while pos < len(raw):
        rec = _record_at(raw, pos, t_prev)
        end = pos + _LOG_RECORD.size + rec[2] if rec else None
        if rec and end <= len(raw) and _chain_at(raw, end, rec[0], 2, strict=True):
            records.append((rec[0], rec[1], raw[pos + _LOG_RECORD.size:end]))
            t_prev, pos = rec[0], end
            continue
        q = _resync(raw, pos + 1, t_prev)
        if rec and end <= len(raw) and (q is None or q > end - _LOG_RECORD.size):
            # This record is whole and no record starts inside it: the damage lies further on.
            # A chain starting in its last bytes is the next record with the front of its
            # header lost (bytes cut out there): keep both.
            records.append((rec[0], rec[1], raw[pos + _LOG_RECORD.size:end]))
            t_prev, pos = rec[0], end
            if q is not None and q < end:
                skipped.append([q, end - q, "overlap"])
                pos = q
            continue
        if q is None:
            cut = (rec is not None and end > len(raw)) or pos > len(raw) - _LOG_RECORD.size
            why = "record cut short at the end" if cut else "damaged"
            skipped.append([pos, len(raw) - pos, why])
            break
        skipped.append([pos, q - pos, "damaged"])
        pos = q
    if skipped:
        meta["skipped"] = skipped
        warnings.warn(LogDamageWarning(_skipped_line(path, skipped)), stacklevel=2)
    return meta, records


def _skipped_line(path, skipped) -> str:
    def one(pos, n, why):
        if why == "overlap":
            return f"damaged record header at {pos} (its first {n} bytes lie in the record before)"
        if why == "damaged":
            return f"skipped {n} damaged bytes at {pos}..{pos + n}"
        return f"{why}: {n} bytes at {pos}..{pos + n} not read"
    if len(skipped) <= 2:
        return f"{Path(path).name}: " + "; ".join(one(*s) for s in skipped)
    total = sum(n for _, n, why in skipped if why != "overlap")
    where = ", ".join(f"{p}..{p + n}" for p, n, _ in skipped[:3]) + ", ..."
    return f"{Path(path).name}: skipped {total} damaged bytes in {len(skipped)} places ({where})"

