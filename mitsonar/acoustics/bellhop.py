"""Cross-checks with Bellhop, M. B. Porter's Gaussian/geometric beam model (the Acoustics Toolbox).

`write_env` writes a `SoundSpeedProfile` and a geometry (source depth, receiver depths and
ranges, a flat or sloping bottom) as a Bellhop environment file; run ``bellhop.exe NAME`` on it; read its
arrivals (run type ``'A'``) with `read_arrivals` and its transmission-loss field (run types ``'C'``,
``'I'``, ``'S'``) with `read_shd`, and compare with `mitsonar.acoustics.eigenrays` and
`transmission_loss_field`. The formats are Bellhop's environment, ASCII arrivals and binary shade
files as the Acoustics Toolbox documents them (Porter, *The BELLHOP Manual and User's Guide:
Preliminary Draft*, HLS Research, 2011) and its Python wrapper ``aubellhop`` reads them; the
tests run the ``bellhop.exe`` of ``aubellhop`` 0.2.1 on what `write_env` writes.

What is written: the profile interpolated c-linearly (``'C'``, as mitsonar's), a vacuum surface
(``'V'``), volume absorption in dB/m (``'M'``) on the profile's first line, the profile's samples
down to the bottom (the last at ``water_depth``; below the last sample the speed is held constant,
as mitsonar does), and the bottom: rigid (``'R'``) for a reflection coefficient of 1, an
acousto-elastic half-space without shear (``'A'``) for a `FluidBottom`, or a tabulated
reflection coefficient (``'F'``, a ``.brc`` file next to the ``.env``) for any other number or a
function of the grazing angle. Angles in Bellhop are degrees, positive downward, as mitsonar's
(there in radians); ranges are kilometres in the file.
"""
from __future__ import annotations

import math
import os
import struct

import numpy as np

from mitsonar.acoustics.profile import ProfileError, SoundSpeedProfile
from mitsonar.acoustics.propagation import FluidBottom

__all__ = ["write_env", "read_arrivals", "read_shd", "BELLHOP_ARRIVAL_DTYPE"]

#: One Bellhop arrival: amplitude (pressure re 1 m), phase (deg), delay (s, real and imaginary
#: parts), launch and arrival angles (deg, positive downward) and the bounce counts.
BELLHOP_ARRIVAL_DTYPE = np.dtype([("amplitude", "f8"), ("phase", "f8"), ("time", "f8"), ("time_imag", "f8"),
                                  ("launch", "f8"), ("arrival", "f8"), ("surface_bounces", "i4"),
                                  ("bottom_bounces", "i4"), ("receiver_depth", "f8"), ("range", "f8")])

_RUN_TYPES = {"A": "arrivals (ASCII)", "C": "coherent TL", "I": "incoherent TL", "S": "semi-coherent TL",
              "E": "eigenrays", "R": "ray fan"}


def _values(values):
    return " ".join(repr(float(v)) for v in np.atleast_1d(values))


def write_env(path, profile, source_depth, receiver_depths, ranges, *, water_depth, bottom=1.0, frequency=1000.0,
              absorption=0.0, run_type="A", angles=(-89.0, 89.0), beams=2001, step=0.0, title="mitsonar",
              bottom_slope=0.0):
    """Write ``path`` (``NAME.env``) for ``bellhop.exe NAME``: the profile, a bottom at
    ``water_depth`` (m) with reflection coefficient ``bottom`` (as in
    `mitsonar.acoustics.eigenrays`), one source depth, receiver depths (m) and ranges (m), the run
    type (``'A'`` arrivals, ``'I'`` incoherent TL, ``'C'`` coherent TL, ``'E'`` eigenrays, ``'R'``
    rays; geometric hat-shaped beams in Cartesian coordinates), the fan (``angles`` in degrees,
    ``beams`` rays) and Bellhop's ray step (m; 0: its default, a tenth of the depth). Returns the
    path written. A tabulated bottom goes to ``NAME.brc`` alongside; a ``bottom_slope`` (deg,
    positive deepening with range; ``water_depth`` is then the depth at the source) to a
    bathymetry file ``NAME.bty`` (linear between its two ends)."""
    func = "write_env"
    path = os.fspath(path)
    if not path.endswith(".env"):
        raise ProfileError(f"{func}: {path}: a Bellhop environment file ends in .env")
    if not isinstance(profile, SoundSpeedProfile):
        raise ProfileError(f"{func}: profile {type(profile).__name__} is not a SoundSpeedProfile")
    if run_type not in _RUN_TYPES:
        raise ProfileError(f"{func}: run_type {run_type!r} is not allowed "
                           f"({', '.join(f'{k!r} {v}' for k, v in _RUN_TYPES.items())})")
    D = float(water_depth)
    if not (math.isfinite(D) and D > 0):
        raise ProfileError(f"{func}: water_depth {water_depth!r} is not allowed (a depth > 0 m)")
    rd = np.atleast_1d(np.asarray(receiver_depths, dtype=float))
    rr = np.atleast_1d(np.asarray(ranges, dtype=float))
    if not (0 <= source_depth <= D) or (rd < 0).any() or (rd > D + max(0.0, float(rr.max()) * math.tan(math.radians(
            float(bottom_slope))))).any():
        raise ProfileError(f"{func}: source and receiver depths must lie between 0 and water_depth {D:g} m")
    r_end = float(rr.max()) * 1.02
    tanb = math.tan(math.radians(float(bottom_slope)))
    D0 = D
    D = max(D0, D0 + r_end * tanb)                   # the profile down to the deepest bottom
    d = profile.depths[profile.depths < D]
    z = np.concatenate([[0.0] if d.size == 0 or d[0] > 0 else [], d, [D]])
    c = profile.speed(z)
    base = path[:-4]
    lines = [f"'{title}'", repr(float(frequency)), "1", "'CVM '", f"0 0.0 {D!r}"]
    for k, (zk, ck) in enumerate(zip(z, c)):
        zk, ck = float(zk), float(ck)
        lines.append(f"{zk!r} {ck!r} 0.0 1.0 {float(absorption)!r} /" if k == 0 else f"{zk!r} {ck!r} /")
    star = "*" if bottom_slope else ""
    if star:
        with open(base + ".bty", "w") as f:
            f.write(f"'LS'\n2\n0.0 {D0!r}\n{r_end / 1000.0!r} {D0 + r_end * tanb!r}\n")
    if isinstance(bottom, FluidBottom):
        att = bottom.attenuation * float(frequency) / bottom.sound_speed        # dB/wavelength -> dB/m
        lines += [f"'A{star}' 0.0", f"{D!r} {bottom.sound_speed!r} 0.0 {bottom.density_ratio!r} {att!r} /"]
    elif not callable(bottom) and complex(bottom) == 1.0:
        lines.append(f"'R{star}' 0.0")
    else:
        lines.append(f"'F{star}' 0.0")
        grazing = np.linspace(0.0, 90.0, 901)
        r = (np.asarray(bottom(np.radians(grazing)), complex) * np.ones(grazing.shape) if callable(bottom)
             else np.full(grazing.shape, complex(bottom)))
        with open(base + ".brc", "w") as f:
            f.write(f"{grazing.size}\n")
            for g, v in zip(grazing, r):
                f.write(f"{g!r} {abs(v)!r} {math.degrees(np.angle(v))!r}\n")
    lines += ["1", f"{float(source_depth)!r} /", str(rd.size), f"{_values(rd)} /", str(rr.size),
              f"{_values(rr / 1000.0)} /", f"'{run_type}G'", str(int(beams)),
              f"{float(angles[0])!r} {float(angles[1])!r} /",
              f"{float(step)!r} {D * 1.01!r} {float(rr.max()) / 1000.0 * 1.01!r}"]
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    return path


def read_arrivals(path):
    """Bellhop's ASCII arrivals file (``NAME.arr``, run type ``'A'``, 2-D, one source): a structured
    array of `BELLHOP_ARRIVAL_DTYPE`, one row per arrival, with the receiver depth and range (m)
    it arrives at."""
    path = os.fspath(path)
    with open(path) as f:
        tokens = f.read().split()
    if not tokens or tokens[0].strip("'") != "2D":
        raise ProfileError(f"{path}: not a 2-D Bellhop ASCII arrivals file (first line '2D')")
    pos = 2                                          # '2D', frequency

    def vector():
        nonlocal pos
        n = int(tokens[pos])
        v = np.array(tokens[pos + 1:pos + 1 + n], dtype=float)
        pos += 1 + n
        return v

    sd, rdep, rran = vector(), vector(), vector()
    if sd.size != 1:
        raise ProfileError(f"{path}: {sd.size} source depths; read_arrivals reads one")
    pos += 1                                         # the largest number of arrivals
    rows = []
    for zr in rdep:
        for r in rran:
            n = int(tokens[pos])
            pos += 1
            for _ in range(n):
                v = tokens[pos:pos + 8]
                pos += 8
                rows.append((float(v[0]), float(v[1]), float(v[2]), float(v[3]), float(v[4]), float(v[5]),
                             int(v[6]), int(v[7]), float(zr), float(r)))
    return np.array(rows, dtype=BELLHOP_ARRIVAL_DTYPE)


def read_shd(path):
    """Bellhop's binary shade file (``NAME.shd``, one source, one frequency): ``(depths, ranges,
    pressure)``, the receiver depths and ranges (m) and the complex pressure re 1 m of shape
    ``(len(depths), len(ranges))`` (its magnitude is the incoherent field for run type ``'I'``).
    The TL is ``-20 log10 |pressure|``."""
    path = os.fspath(path)
    with open(path, "rb") as f:
        data = f.read()
    recl = struct.unpack_from("<i", data, 0)[0]
    rec = 4 * recl
    grid_type = data[rec:rec + 10].decode("ascii", "replace").strip()
    if grid_type != "rectilin":
        raise ProfileError(f"{path}: not a Bellhop shade file of a rectilinear grid ({grid_type!r})")
    nfreq, ntheta, nsx, nsy, nsd, nrd, nrr, _ = struct.unpack_from("<7if", data, 2 * rec)
    if nfreq != 1 or ntheta != 1 or nsd != 1:
        raise ProfileError(f"{path}: {nsd} sources, {nfreq} frequencies; read_shd reads one of each")
    depths = np.frombuffer(data, "<f4", nrd, 8 * rec).astype(float)
    ranges = np.frombuffer(data, "<f4", nrr, 9 * rec).astype(float)
    p = np.zeros((nrd, nrr), complex)
    for i in range(nrd):
        v = np.frombuffer(data, "<f4", 2 * nrr, (10 + i) * rec).astype(float)
        p[i] = v[0::2] + 1j * v[1::2]
    return depths, ranges, p
