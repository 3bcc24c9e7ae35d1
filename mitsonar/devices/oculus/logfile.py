"""Oculus ``.oculus`` logs, version 1 (the binary one Blueprint's viewer writes): `OculusLogWriter`,
`write_log`, `read_log`, `read_scans`, `is_oculus_log`, and `scan_to_ping` (a rendered multibeam
scan as the simple ping result a head would send).

Layout (little-endian), as oculus-python carries it (``bps_oculus/logger/v1.py``: ``RmLogHeader``
``'<2I16s2H4xqd'``, ``RmLogItem`` ``'<2I2H4xdH2x2I4x'``, record types ``eRecordTypes``; the reader
``bps_oculus/io.py`` ``process_v1``)::

    file header (48 bytes)   0 fileHeader  u32  0x11223344
                             4 sizeHeader  u32  48
                             8 source      16s  "Oculus"
                            24 version     u16  1
                            26 encryption  u16  0
                            28 (4 bytes padding)
                            32 key         i64  0
                            40 time        f64  the log's start, Unix seconds
    items (40 bytes each)    0 itemHeader  u32  0xaabbccdd
                             4 sizeHeader  u32  40
                             8 type        u16  10 (rt_oculusSonar)
                            10 version     u16  1
                            12 (4 bytes padding)
                            16 time        f64  the item's time, Unix seconds
                            24 compression u16  0
                            26 (2 bytes padding)
                            28 originalSize u32
                            32 payloadSize  u32
                            36 (4 bytes padding)
                             then payloadSize bytes: one Oculus message (a simple ping result)

`read_log` skips items of other types and messages that are no simple ping result (counted in
its ``skipped``); an item whose compression is not 0 is read as Qt's ``qCompress`` (a 4-byte
big-endian length, then zlib) if it inflates to ``originalSize``, else refused. A file that is
not a version 1 log, or is cut inside an item, raises ValueError naming the file, the byte
offset and the field.
"""
from __future__ import annotations

import struct
import time
import zlib
from collections import Counter
from pathlib import Path

import numpy as np

from mitsonar.devices.oculus.protocol import EXT_32BIT, FLAG, FireMessage, OculusError, PingResult, decode

__all__ = ["FILE_MAGIC", "ITEM_MAGIC", "RT_OCULUS_SONAR", "OculusLogWriter", "write_log", "read_log",
           "read_scans", "is_oculus_log", "scan_to_ping"]

FILE_MAGIC = 0x11223344
ITEM_MAGIC = 0xAABBCCDD
RT_OCULUS_SONAR = 10
_FILE = struct.Struct("<2I16s2H4xqd")       # 48
_ITEM = struct.Struct("<2I2H4xdH2x2I4x")    # 40


def is_oculus_log(path) -> bool:
    """Does ``path`` start like a version 1 ``.oculus`` log?"""
    try:
        with open(path, "rb") as f:
            head = f.read(8)
    except OSError:
        return False
    return len(head) == 8 and struct.unpack("<2I", head) == (FILE_MAGIC, _FILE.size)


def scan_to_ping(scan, *, ping_id: int = 0, version: int = 2, gains: bool = True, mode: int = 1,
                 ping_start_time: float = 0.0) -> PingResult:
    """A multibeam `mitsonar.scan.Scan` as the simple ping result a head would send: beams its rows
    (bearings rounded to 0.01 degree), range lines its bins (``rangeResolution`` the bin width; a
    window starting above 0 m gets zero lines below it, so line i still covers
    ``[i, i + 1) x rangeResolution``), the image its data (8-bit samples of bytes; 16- and 32-bit
    ones, as the fire message asks them, of a wider A/D's uint16, uint32 codes; 32-bit ones in a
    version 2 result only), at gain 100 % and gamma 1.
    ValueError if the scan is no multibeam or ``range_min`` is no whole number of bins."""
    if not scan.sonar_kind.fan_frame:
        raise ValueError(f"scan_to_ping: a {scan.kind} scan is no Oculus ping (a multibeam frame)")
    w = scan.bin_width
    lead = scan.range_min / w
    if abs(lead - round(lead)) > 1e-6:
        raise ValueError(f"scan_to_ping: range_min {scan.range_min:g} m is not a whole number of "
                         f"{w:g} m bins (an Oculus image starts at 0 m)")
    lead = int(round(lead))
    data = np.asarray(scan.data)
    if data.dtype == np.uint32 and version != 2:
        raise ValueError("scan_to_ping: a scan of 32-bit data (uint32) needs a version 2 ping result "
                         "(32-bit samples are its extFlags 0x200), not version 1")
    image = np.zeros((lead + scan.n_bins, scan.n_pings), data.dtype)
    image[lead:] = data.T
    bearings = np.round(np.degrees(scan.bearings) * 100)
    if np.any(np.abs(bearings) > 32767):
        raise ValueError("scan_to_ping: a bearing beyond +-327.67 degrees does not fit the ping result")
    flags = FLAG["range_as_meters"] | FLAG["simple_return"] | (FLAG["send_gain"] if gains else 0)
    flags |= FLAG["512_beams"] if scan.n_pings > 256 else 0
    flags |= FLAG["data_16bit"] if data.dtype == np.uint16 else 0
    fire = FireMessage(master_mode=mode, ping_rate=0, gamma=255, flags=flags, range=float(scan.range_max),
                       gain=100.0, speed_of_sound=float(scan.sound_speed), salinity=35.0, version=version,
                       ext_flags=EXT_32BIT if data.dtype == np.uint32 else 0)
    freq = scan.meta.frequency or 0.0
    return PingResult(fire, image, bearings.astype(np.int16), float(w),
                      gains=np.ones(image.shape[0], np.float32) if gains else None, ping_id=ping_id,
                      frequency=float(freq), speed_of_sound_used=float(scan.sound_speed),
                      ping_start_time=ping_start_time)


class OculusLogWriter:
    """Write a version 1 ``.oculus`` log: ``add(message, t=None)`` appends one item (a
    `PingResult`, a multibeam `mitsonar.scan.Scan` (`scan_to_ping`), or a whole message's bytes)
    at Unix time ``t`` (default now). Written under a temporary name and renamed at `close`
    (`mitsonar.devices.rawlog.part_name`); `discard` removes it."""

    def __init__(self, path, start_time: float | None = None):
        from mitsonar.devices.rawlog import part_name
        self.path = Path(path)
        self._part = part_name(self.path)
        self.start_time = time.time() if start_time is None else float(start_time)
        try:
            self._f = open(self._part, "wb")
        except OSError as e:
            raise type(e)(f"{self.path}: cannot be written ({e.strerror or e})") from None
        self._f.write(_FILE.pack(FILE_MAGIC, _FILE.size, b"Oculus", 1, 0, 0, self.start_time))
        self.items = 0

    def add(self, message, t: float | None = None) -> None:
        if hasattr(message, "sonar_kind"):
            message = scan_to_ping(message, ping_id=self.items)
        data = message.encode() if isinstance(message, PingResult) else bytes(message)
        t = time.time() if t is None else float(t)
        self._f.write(_ITEM.pack(ITEM_MAGIC, _ITEM.size, RT_OCULUS_SONAR, 1, t, 0, len(data), len(data)) + data)
        self.items += 1

    def close(self) -> None:
        import os
        if self._f is not None:
            self._f.close()
            self._f = None
            os.replace(self._part, self.path)

    def discard(self) -> None:
        import os
        if self._f is not None:
            self._f.close()
            self._f = None
        try:
            os.remove(self._part)
        except FileNotFoundError:
            pass

    def __enter__(self):
        return self

    def __exit__(self, exc_type, *exc):
        if exc_type is None:
            self.close()
        else:
            self.discard()


def write_log(path, pings, times=None, start_time: float | None = None) -> Path:
    """Write ``pings`` (PingResults, multibeam Scans or message bytes) as a ``.oculus`` log;
    ``times`` (Unix s) per item, default the start time plus 0.1 s per item."""
    pings = list(pings)
    with OculusLogWriter(path, start_time) as w:
        for i, p in enumerate(pings):
            w.add(p, w.start_time + 0.1 * i if times is None else times[i])
    return Path(path)


def read_log(path) -> tuple[dict, list[tuple[float, PingResult]]]:
    """``(info, [(time, ping_result)])`` of a version 1 ``.oculus`` log; ``info``: ``start_time``,
    ``version``, ``source``, ``skipped`` (a Counter of why items were skipped)."""
    path = Path(path)
    raw = path.read_bytes()
    if len(raw) < _FILE.size:
        raise ValueError(f"{path}: {len(raw)} bytes is no .oculus log (its header is {_FILE.size} bytes)")
    magic, size, source, version, encryption, _key, t0 = _FILE.unpack_from(raw)
    if magic != FILE_MAGIC:
        raise ValueError(f"{path}: fileHeader 0x{magic:08x} is not 0x{FILE_MAGIC:08x} (no version 1 .oculus log)")
    if size != _FILE.size:
        raise ValueError(f"{path}: sizeHeader {size} is not allowed ({_FILE.size})")
    if encryption:
        raise ValueError(f"{path}: encryption {encryption} is not allowed (0: an unencrypted log)")
    info = {"start_time": t0, "version": version, "source": source.split(b"\0")[0].decode("ascii", "replace"),
            "skipped": Counter()}
    out = []
    pos = _FILE.size
    while pos < len(raw):
        if pos + _ITEM.size > len(raw):
            raise ValueError(f"{path}: byte {pos}: an item header cut short ({len(raw) - pos} of {_ITEM.size} bytes)")
        magic, isize, rtype, _ver, t, comp, orig, n = _ITEM.unpack_from(raw, pos)
        if magic != ITEM_MAGIC:
            raise ValueError(f"{path}: byte {pos}: itemHeader 0x{magic:08x} is not 0x{ITEM_MAGIC:08x}")
        if isize != _ITEM.size:
            raise ValueError(f"{path}: byte {pos}: item sizeHeader {isize} is not allowed ({_ITEM.size})")
        start = pos + _ITEM.size
        if start + n > len(raw):
            raise ValueError(f"{path}: byte {pos}: payloadSize {n} runs past the end of the file")
        payload = raw[start:start + n]
        pos = start + n
        if rtype != RT_OCULUS_SONAR:
            info["skipped"][f"record type {rtype}"] += 1
            continue
        if comp:
            try:
                payload = zlib.decompress(payload[4:])
            except zlib.error:
                raise ValueError(f"{path}: byte {pos - n - _ITEM.size}: compression {comp} is not allowed "
                                 f"(0, or qCompress's zlib)") from None
            if len(payload) != orig:
                raise ValueError(f"{path}: byte {pos - n - _ITEM.size}: inflated to {len(payload)} bytes, "
                                 f"originalSize says {orig}")
        try:
            m = decode(payload)
        except OculusError as e:
            raise ValueError(f"{path}: byte {start}: {e}") from None
        if isinstance(m, PingResult):
            out.append((t, m))
        else:
            info["skipped"][f"message 0x{getattr(getattr(m, 'header', None), 'msg_id', 0):02x}"] += 1
    return info, out


def read_scans(path, pose=None) -> list:
    """The multibeam `mitsonar.scan.Scan` of every ping of a ``.oculus`` log
    (`mitsonar.devices.oculus.head.ping_to_scan`, ``meta['log']`` the path). A ping that makes
    no scan (a ``rangeResolution`` of 0, say) raises ValueError naming the file and the ping."""
    from mitsonar.devices.oculus.head import ping_to_scan
    _info, pings = read_log(path)
    scans = []
    for k, (t, p) in enumerate(pings):
        try:
            scans.append(ping_to_scan(p, pose, t, {"log": str(path)}))
        except ValueError as e:
            raise ValueError(f"{path}: ping {k} of the log: {e}") from None
    return scans
