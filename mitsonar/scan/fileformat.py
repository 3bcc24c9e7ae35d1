"""The scan file format: OpenEXR (``.exr``) and numpy (``.npz``), both lossless, metadata included.

This module knows the format, not the `Scan` class: `write` takes any object with the Scan's
fields, `read` returns the fields a Scan is built from (``Scan.save`` and `mitsonar.load_scan`
use it).

EXR layout (one scanline part, ZIP compression, lossless)
---------------------------------------------------------
The image is ``n_pings`` rows by ``n_bins`` columns (row k is ping k, column j is bin j), with
three channels:

============= ========== ===========================================================================
channel       pixel type content
============= ========== ===========================================================================
``intensity`` FLOAT      ``Scan.intensity``: noise-free echo energy per bin (float32, bit-exact)
``data``      UINT       ``Scan.data``: device bytes 0..255 (EXR has no 8-bit type; stored as uint32)
``Y``         FLOAT      a copy of ``intensity`` under the luminance name, so that EXR tools that know
                         only RGB/Y images (image viewers; OpenCV's ``imread`` once
                         ``OPENCV_IO_ENABLE_OPENEXR=1`` is in the environment before ``import cv2``,
                         as its EXR codec is off by default) open the scan as a grey float image;
                         files written before it have no ``Y`` and read the same
============= ========== ===========================================================================

Everything else lives in one string header attribute, ``mitsonar``, holding JSON (the OpenEXR
binding stores Python floats as float32; JSON holds Python's float repr, which round-trips exactly),
guarded by the string attribute ``mitsonar_crc32`` (CRC-32 of that text, 8 hex digits):

=================== ====================================================================================
key                 value
=================== ====================================================================================
format, version     ``"mitsonar-scan"``, ``1`` (the marker of our files; newer versions are refused)
mitsonar_version    version of the writer
n_pings, n_bins     image size
ranges, bearings    lists of floats (metres, radians)
poses               ``n_pings`` x 4 x 4 nested lists (world transform of each ping's beam frame)
times               list of floats: seconds of each ping from the scan start (absent in files
                    written before scans had times: they load with times None, i.e. zeros)
range_min/max, beam_pattern, beamwidth_h, beamwidth_v, kind, sound_speed, absorption
electronics, meta   the Scan's settings and metadata as dicts (`ElectronicsSettings.to_dict`,
                    `ScanMeta.to_dict`; numpy arrays, numpy scalars and tuples are tagged and restored);
                    an ``electronics`` written by mitsonar 0.2.0 (a ``source_level`` below 150 dB
                    and no ``receiver_sensitivity``: the old calibration constant) is read as
                    source level 200 dB and the sensitivity that keeps their sum
data_type           ``"uint16"`` or ``"uint32"`` for a scan of a wider A/D (``bit_depth`` 16 or 32);
                    absent for bytes (uint8)
checksums           CRC-32 of the intensity (float32, little endian) and data (its type, little
                    endian) bytes
=================== ====================================================================================

The ``.npz`` file holds the arrays ``intensity`` (float32), ``data`` (uint8, or the header's
``data_type``), ``ranges``,
``bearings``, ``poses``, ``times`` (float64; ``times`` optional, as above) natively, the same JSON (without the arrays) in the 0-d
string array ``header`` and its CRC-32 in the 0-d uint32 array ``header_crc32``; it loads with
``numpy.load(path, allow_pickle=False)``.

Any problem with a file (missing, truncated, corrupt, foreign, wrong extension) raises
`ScanFileError`, a ``ValueError`` whose message names the file and says what is wrong.
"""
from __future__ import annotations

import base64
import contextlib
import json
import os
import sys
import zlib
from typing import Any

import numpy as np

from mitsonar._checks import first_line
from mitsonar._files import check_output_file, replacing
from mitsonar.scan.migrations import migrate_settings

FORMAT = "mitsonar-scan"
FORMAT_VERSION = 1
HEADER_ATTRIBUTE = "mitsonar"
CRC_ATTRIBUTE = "mitsonar_crc32"  # CRC-32 of the header text, 8 hex digits: a flipped digit is caught
EXTENSIONS = (".exr", ".npz")

_EXR_MAGIC = b"\x76\x2f\x31\x01"
_ZIP_MAGIC = b"PK\x03\x04"
_SCALARS = ("range_min", "range_max", "beam_pattern", "beamwidth_h", "beamwidth_v", "kind",
            "sound_speed", "absorption")
_ARRAYS = ("ranges", "bearings", "poses")
_OPTIONAL_ARRAYS = ("times",)   # added later: a file without them loads with the Scan's default


class ScanFileError(ValueError):
    """A scan file that cannot be read or written; the message names the file and the problem."""


# ----------------------------------------------------------------------------------------------

def write(scan, path) -> None:
    """Write ``scan`` (a `Scan`, checked by the caller) losslessly to ``path``, ``.exr`` or ``.npz``
    by the extension, atomically (a temporary file renamed into place).

    Raises `ScanFileError` for an unknown extension, a path that is a directory or in a missing
    folder, an empty scan, or metadata that JSON cannot hold exactly (non-string dict keys,
    objects other than numbers, strings, bools, None, lists, tuples, dicts, numpy arrays and scalars).
    """
    path = os.fspath(path)
    ext = extension(path)
    if scan.n_pings == 0 or scan.n_bins == 0:
        raise ScanFileError(f"{path}: cannot save an empty scan ({scan.n_pings} pings x {scan.n_bins} bins)")
    header = _header(scan, with_arrays=(ext == ".exr"), path=path)
    text = json.dumps(header, allow_nan=True, separators=(",", ":"))
    # Checked here so that the message names the user's path, not the temporary file's.
    check_output_file(path, ScanFileError, words={"directory": "{path}: is a directory; give a file name ending in {ext}"})
    try:
        with replacing(path) as tmp:
            if ext == ".exr":
                _write_exr(scan, text, tmp)
            else:
                _write_npz(scan, text, tmp)
    except OSError as exc:  # its text names the temporary file
        raise ScanFileError(f"{path}: cannot be written ({exc.strerror or exc})") from None


def read(path) -> tuple[dict[str, Any], str]:
    """The fields of the scan in ``path`` (keyword arguments of `Scan`) and where the file keeps
    its arrays (``'channel'`` in EXR; ``'array'`` in NPZ), for naming a field the Scan refuses.

    Raises `ScanFileError` for a missing, truncated, corrupt or foreign file or an unknown extension.
    """
    path = os.fspath(path)
    ext = extension(path)
    if os.path.isdir(path):
        raise ScanFileError(f"{path}: is a directory, not a scan file")
    if not os.path.isfile(path):
        raise ScanFileError(f"{path}: no such file")
    try:
        with open(path, "rb") as fh:
            magic = fh.read(4)
    except OSError as exc:
        raise ScanFileError(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if ext == ".exr":
        if magic != _EXR_MAGIC:
            raise ScanFileError(f"{path}: not an OpenEXR file (bad magic number)")
        return _read_exr(path)
    if magic != _ZIP_MAGIC:
        raise ScanFileError(f"{path}: not a numpy .npz file (not a zip archive)")
    return _read_npz(path)


# ----------------------------------------------------------------------------------------------
# header

#: the types a scan's ``data`` may have: bytes, or the codes of a 16- or 32-bit A/D
DATA_TYPES = ("uint8", "uint16", "uint32")

def extension(path: str) -> str:
    """The lower-case extension of a scan file, ``.exr`` or ``.npz`` (else `ScanFileError`)."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in EXTENSIONS:
        raise ScanFileError(f"{path}: unknown scan file extension {ext or '(none)'!r}; use .exr or .npz")
    return ext


def _header(scan, with_arrays: bool, path: str) -> dict[str, Any]:
    from mitsonar._version import __version__

    head: dict[str, Any] = {"format": FORMAT, "version": FORMAT_VERSION, "mitsonar_version": __version__,
                            "n_pings": scan.n_pings, "n_bins": scan.n_bins}
    for name in _SCALARS:
        head[name] = _encode(getattr(scan, name), f"{path}: {name}")
    if with_arrays:
        head["ranges"] = scan.ranges.tolist()
        head["bearings"] = scan.bearings.tolist()
        head["poses"] = scan.poses.tolist()
        head["times"] = scan.times.tolist()
    head["electronics"] = _encode(scan.electronics.to_dict(), f"{path}: electronics")
    head["meta"] = _encode(scan.meta.to_dict(), f"{path}: meta")
    if scan.data.dtype != np.uint8:
        head["data_type"] = str(scan.data.dtype)
    head["checksums"] = _checksums(scan.intensity, scan.data)
    return head


def _checksums(intensity: np.ndarray, data: np.ndarray) -> dict[str, int]:
    return {"intensity": zlib.crc32(np.ascontiguousarray(intensity, dtype="<f4").tobytes()),
            "data": zlib.crc32(np.ascontiguousarray(data, dtype=data.dtype.newbyteorder("<")).tobytes())}


def _encode(obj, where: str):
    """JSON-ready copy of obj; tuples, numpy arrays and numpy scalars are tagged to come back as such."""
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, (np.bool_,)):
        return bool(obj)
    if type(obj) in (int, float):
        return obj
    if isinstance(obj, np.integer):
        return {"__numpy_scalar__": np.dtype(type(obj)).str, "value": int(obj)}
    if isinstance(obj, (float, np.floating)):
        # np.float32 etc.: widening to a Python float is exact; the tag restores the type.
        return {"__numpy_scalar__": np.dtype(type(obj)).str, "value": float(obj)}
    if isinstance(obj, int):  # an int subclass (IntEnum, ...): its plain value
        return int(obj)
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind not in "biuf":
            raise ScanFileError(f"{where}: numpy arrays of dtype {obj.dtype} cannot be stored (numbers only)")
        arr = np.ascontiguousarray(obj)
        return {"__ndarray__": base64.b64encode(arr.tobytes()).decode("ascii"), "dtype": arr.dtype.str,
                "shape": list(arr.shape)}
    if isinstance(obj, tuple):
        return {"__tuple__": [_encode(v, where) for v in obj]}
    if isinstance(obj, list):
        return [_encode(v, where) for v in obj]
    if isinstance(obj, dict):
        out = {}
        for key, value in obj.items():
            if not isinstance(key, str):
                raise ScanFileError(f"{where}: key {key!r} is not a string; scan metadata keys must be strings")
            if key.startswith("__") and key.endswith("__"):
                raise ScanFileError(f"{where}: key {key!r} is reserved")
            out[key] = _encode(value, f"{where}[{key!r}]")
        return out
    raise ScanFileError(f"{where}: a {type(obj).__name__} cannot be stored exactly (use numbers, strings, "
                        "bools, None, lists, tuples, dicts or numpy arrays)")


def _decode(obj):
    if isinstance(obj, list):
        return [_decode(v) for v in obj]
    if isinstance(obj, dict):
        if "__ndarray__" in obj:
            raw = base64.b64decode(obj["__ndarray__"].encode("ascii"), validate=True)
            return np.frombuffer(raw, dtype=np.dtype(obj["dtype"])).reshape(obj["shape"]).copy()
        if "__numpy_scalar__" in obj:
            return np.dtype(obj["__numpy_scalar__"]).type(obj["value"])
        if "__tuple__" in obj:
            return tuple(_decode(v) for v in obj["__tuple__"])
        return {k: _decode(v) for k, v in obj.items()}
    return obj


def _crc_text(text: str) -> int:
    return zlib.crc32(text.encode("utf-8"))


def _parse_header(path: str, text, crc) -> dict[str, Any]:
    if isinstance(text, bytes):
        try:
            text = text.decode("utf-8")
        except UnicodeDecodeError:
            raise ScanFileError(f"{path}: the '{HEADER_ATTRIBUTE}' header is not UTF-8 text (corrupt file)") from None
    if not isinstance(text, str):
        raise ScanFileError(f"{path}: the '{HEADER_ATTRIBUTE}' header is not a string")
    if crc is None:
        raise ScanFileError(f"{path}: the header checksum is missing (not a mitsonar scan, or a damaged one)")
    if crc != _crc_text(text):
        raise ScanFileError(f"{path}: the header does not match its checksum (corrupt file)")
    try:
        head = json.loads(text)
    except ValueError as exc:
        raise ScanFileError(f"{path}: the '{HEADER_ATTRIBUTE}' header is not valid JSON (corrupt file: {exc})") from None
    if not isinstance(head, dict) or head.get("format") != FORMAT:
        raise ScanFileError(f"{path}: not a mitsonar scan (no '{FORMAT}' format marker in the header)")
    version = head.get("version")
    if not isinstance(version, int) or version < 1:
        raise ScanFileError(f"{path}: bad format version {version!r}")
    if version > FORMAT_VERSION:
        raise ScanFileError(f"{path}: written by a newer mitsonar (format version {version}, "
                            f"this one reads up to {FORMAT_VERSION}); upgrade mitsonar")
    return head


def _build(path: str, head: dict[str, Any], intensity, data, arrays: dict[str, Any], stored_as: str):
    """The Scan fields of a file's parts (and ``stored_as``); `stored_as` is where the file keeps intensity and data
    ('channel' in EXR) and, in NPZ ('array'), also ranges, bearings and poses."""
    try:
        n_pings, n_bins = head["n_pings"], head["n_bins"]
        scalars = {name: _decode(head[name]) for name in _SCALARS}
        # Files of mitsonar 0.2.0 hold the calibration constant as 'source_level'.
        electronics = migrate_settings(_decode(head["electronics"]))
        meta = _decode(head["meta"])
        checks = head["checksums"]
    except (KeyError, TypeError, ValueError) as exc:
        raise ScanFileError(f"{path}: the header lacks or garbles {exc}") from None
    for name, value in (("n_pings", n_pings), ("n_bins", n_bins)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 1:
            raise ScanFileError(f"{path}: header '{name}': {value!r} is not allowed (a count >= 1)")
    if intensity.shape != (n_pings, n_bins) or data.shape != (n_pings, n_bins):
        raise ScanFileError(f"{path}: channels are {intensity.shape} and {data.shape}, the header says "
                            f"{n_pings} pings x {n_bins} bins")
    if intensity.dtype != np.float32:
        raise ScanFileError(f"{path}: channel 'intensity' is {intensity.dtype}, expected float32")
    data_type = head.get("data_type", "uint8")
    if data_type not in DATA_TYPES:
        raise ScanFileError(f"{path}: header 'data_type': {data_type!r} is not allowed (one of {', '.join(DATA_TYPES)})")
    top = np.iinfo(data_type).max
    if data.dtype.kind not in "ui" or (data.size and (data.min() < 0 or data.max() > top)):
        raise ScanFileError(f"{path}: channel 'data' does not hold {data_type} values 0..{top}")
    data = data.astype(data_type)
    if _checksums(intensity, data) != checks:
        raise ScanFileError(f"{path}: pixel data do not match their checksums (corrupt file)")
    return dict(intensity=intensity, data=data, electronics=electronics, meta=meta, **arrays, **scalars), stored_as


# ----------------------------------------------------------------------------------------------
# EXR

def _write_exr(scan, text: str, path: str) -> None:
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, HEADER_ATTRIBUTE: text,
              CRC_ATTRIBUTE: f"{_crc_text(text):08x}"}
    intensity = np.ascontiguousarray(scan.intensity, dtype=np.float32)
    # 'Y': the same floats under the name EXR tools read as a grey image (OpenCV opens no other).
    channels = {"intensity": intensity, "data": np.ascontiguousarray(scan.data, dtype=np.uint32),
                "Y": intensity.copy()}
    with OpenEXR.File(header, channels) as f:
        f.write(path)


def _read_exr(path: str) -> tuple[dict[str, Any], str]:
    import OpenEXR

    try:
        with _c_output_silenced(), OpenEXR.File(path, separate_channels=True) as f:
            # The binding empties header and channels when the file closes: copy them out.
            header = dict(f.header())
            channels = {name: np.array(ch.pixels) for name, ch in f.channels().items()}
    except Exception as exc:  # the binding raises RuntimeError, ValueError, UnicodeDecodeError, ...
        raise ScanFileError(f"{path}: unreadable OpenEXR file (truncated or corrupt: {first_line(exc)})") from None
    if HEADER_ATTRIBUTE not in header:
        raise ScanFileError(f"{path}: an OpenEXR image but not a mitsonar scan (no '{HEADER_ATTRIBUTE}' "
                            "header attribute)")
    crc = header.get(CRC_ATTRIBUTE)
    try:
        crc = int(crc, 16) if isinstance(crc, str) and len(crc) == 8 else None
    except ValueError:
        crc = None
    head = _parse_header(path, header[HEADER_ATTRIBUTE], crc)
    for name in ("intensity", "data"):
        if name not in channels:
            raise ScanFileError(f"{path}: channel '{name}' is missing (channels: {', '.join(sorted(channels)) or 'none'})")
    try:
        arrays = {name: head[name] for name in _ARRAYS}  # Scan checks that they hold numbers
        arrays.update({name: head[name] for name in _OPTIONAL_ARRAYS if name in head})
    except KeyError as exc:
        raise ScanFileError(f"{path}: the header lacks or garbles {exc}") from None
    return _build(path, head, channels["intensity"], channels["data"], arrays, "channel")


@contextlib.contextmanager
def _c_output_silenced():
    """Keep the OpenEXR library's own prints about a damaged file (C-level stdout/stderr) off the
    user's terminal: the ScanFileError says it in one line. A no-op where the descriptors are not
    usable (embedded interpreters, closed streams)."""
    saved = []
    try:
        for stream in (sys.stdout, sys.stderr):
            if stream is not None:
                stream.flush()
        sink = os.open(os.devnull, os.O_WRONLY)
        try:
            for fd in (1, 2):
                saved.append((fd, os.dup(fd)))
                os.dup2(sink, fd)
        finally:
            os.close(sink)
    except (OSError, ValueError, AttributeError):
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)
        saved = []
    try:
        yield
    finally:
        for fd, copy in saved:
            os.dup2(copy, fd)
            os.close(copy)


# ----------------------------------------------------------------------------------------------
# NPZ

def _write_npz(scan, text: str, path: str) -> None:
    with open(path, "wb") as fh:
        np.savez_compressed(fh, intensity=scan.intensity.astype(np.float32), data=scan.data,
                            ranges=scan.ranges, bearings=scan.bearings, poses=scan.poses, times=scan.times,
                            header=np.array(text),
                            header_crc32=np.array(_crc_text(text), dtype=np.uint32))


def _read_npz(path: str) -> tuple[dict[str, Any], str]:
    names = ("intensity", "data", "ranges", "bearings", "poses", "header")
    try:
        with np.load(path, allow_pickle=False) as z:
            present = set(z.files)
            if "header" not in present:
                raise ScanFileError(f"{path}: a numpy archive but not a mitsonar scan (no 'header' array)")
            missing = [n for n in names if n not in present]
            if missing:
                raise ScanFileError(f"{path}: array(s) {', '.join(missing)} missing")
            arrays = {n: z[n] for n in names + tuple(n for n in _OPTIONAL_ARRAYS if n in present)}
            crc = z["header_crc32"] if "header_crc32" in present else None
    except ScanFileError:
        raise
    except Exception as exc:  # zipfile.BadZipFile, ValueError (pickled objects), EOFError, zlib.error, ...
        raise ScanFileError(f"{path}: unreadable numpy archive (truncated or corrupt: {first_line(exc)})") from None
    header = arrays.pop("header")
    if header.shape != () or header.dtype.kind != "U":
        raise ScanFileError(f"{path}: the 'header' array is not a string")
    if crc is not None:
        crc = int(crc) if crc.shape == () and crc.dtype == np.uint32 else -1
    head = _parse_header(path, str(header), crc)
    for name in _ARRAYS + tuple(n for n in _OPTIONAL_ARRAYS if n in arrays):
        if arrays[name].dtype != np.float64:
            raise ScanFileError(f"{path}: array '{name}' is {arrays[name].dtype}, expected float64")
    intensity, data = arrays.pop("intensity"), arrays.pop("data")
    if data.dtype != np.dtype(head.get("data_type", "uint8")):
        raise ScanFileError(f"{path}: array 'data' is {data.dtype}, expected {head.get('data_type', 'uint8')}")
    return _build(path, head, intensity, data, arrays, "array")
