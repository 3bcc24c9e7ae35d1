"""Side-scan products of a scan: its channels, the altitude from the first bottom return, the
slant-range to ground-range correction, and the waterfall picture's array.

A side-scan scan (``kind='sidescan'``) has one row per ping and channel: with ``side='both'`` the
port pings, then the starboard pings (``scan.channel``: 0 port, 1 starboard). Row k's pose is its
channel's beam frame (`mitsonar.geometry.frames.sidescan_rotation`): ``poses[k][:3, 3]`` the transducer,
``poses[k][:3, 2]`` the boresight, whose horizontal part points across the track to that side.

Slant to ground range (the classic flat-bottom correction, e.g. Blondel, "The Handbook of
Sidescan Sonar", Springer 2009, section 4.3): an echo at slant range ``r`` from a head at altitude
``a`` above a flat bottom comes from the across-track ground distance ``g = sqrt(r^2 - a^2)``;
the ground-range image samples each row at ``r(g) = sqrt(g^2 + a^2)``. Over a known seabed
``z = f(x, y)`` the ground point ``q = p + g u`` (``p`` the transducer, ``u`` the horizontal unit
vector across the track to the row's side) is at slant range ``sqrt(g^2 + (p_z - f(q))^2)``.
Ranges before the first bottom return (the nadir gap, ``r < a``) have no ground position.

``use="data"`` values are device levels 0..255: the bytes, or the uint16/uint32 codes of a 16- or
32-bit A/D times ``255 / full scale`` (not rounded: the finer levels kept), so that products
(waterfalls, ground range, mosaics) of scans of any A/D width share one scale.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import mitsonar.kinds as kinds
from mitsonar.geometry.frames import PORT, SIDES, STARBOARD
from mitsonar.scan.model import data_levels

USES = ("data", "intensity")


def _check_sidescan(scan, where):
    kind = kinds.kind_of(scan)
    if kind is None or not kind.sided:
        raise ValueError(f"{where}: needs a side-scan scan (kind {kinds.which('sided')}), "
                         f"got kind {getattr(scan, 'kind', None)!r}")


def _values(scan, use, where):
    if use not in USES:
        raise ValueError(f"{where} 'use': {use!r} is not allowed (one of {', '.join(USES)})")
    if use == "data":               # a 16- or 32-bit A/D's codes: on the bytes' scale
        return data_levels(scan.data)
    return np.asarray(getattr(scan, use), dtype=np.float64)


def channel_rows(scan, side) -> np.ndarray:
    """Indices of the rows of ``scan`` from ``side`` (``port``/``starboard``, or channel 0/1), in ping
    order."""
    _check_sidescan(scan, "channel_rows")
    ch = {"port": PORT, "starboard": STARBOARD, PORT: PORT, STARBOARD: STARBOARD}.get(side)
    if ch is None or isinstance(side, bool):
        raise ValueError(f"channel_rows 'side': {side!r} is not allowed (port, starboard, 0 or 1)")
    return np.flatnonzero(scan.channel == ch)


def select_side(scan, side):
    """A `Scan` of one side's rows of a side-scan ``scan`` (``port``/``starboard`` or 0/1): its
    intensity, data, poses and times, with ``meta['side']`` set to that side."""
    import dataclasses

    rows = channel_rows(scan, side)
    name = SIDES[int(scan.channel[rows[0]])] if len(rows) else str(side)
    if not len(rows):
        raise ValueError(f"select_side: the scan has no {name} rows (its side is {scan.meta.side or 'both'!r})")
    return dataclasses.replace(scan, intensity=scan.intensity[rows], data=scan.data[rows], bearings=scan.bearings[rows],
                               poses=scan.poses[rows], times=scan.times[rows], meta=scan.meta.replace(side=name))


def first_return(scan, threshold=1e-3, use="intensity") -> np.ndarray:
    """(n_rows,) slant range (m, bin centre) of each row's first bin above ``threshold`` times the
    median of the row's nonzero values: the first bottom return, i.e. the altitude when the fan
    reaches nadir over a flat bottom (the median, not the peak: a bright target or a corner
    reflector in the row must not hide a weak nadir return). With both channels, each ping's
    altitude is the nearer of its two channels' first returns (they share the nadir). NaN for a row
    with no echo. From ``intensity`` the estimate is exact when the fan reaches nadir and enough
    paths do (a weak tail and few paths give a late first return); from ``data`` noise and
    ring-down come first: give the altitude instead."""
    _check_sidescan(scan, "first_return")
    v = _values(scan, use, "first_return")
    if not (np.isfinite(threshold) and 0 < threshold < 1):
        raise ValueError(f"first_return 'threshold': {threshold!r} is not allowed (a fraction in (0, 1))")
    with np.errstate(invalid="ignore"):
        level = np.nanmedian(np.where(v > 0, v, np.nan), axis=1, keepdims=True) if (v > 0).any() else None
    if level is None:
        return np.full(scan.n_pings, np.nan)
    above = np.isfinite(level) & (v > threshold * np.nan_to_num(level))
    out = scan.ranges[np.argmax(above, axis=1)].astype(np.float64)
    out[~above.any(axis=1)] = np.nan
    ch = scan.channel
    if (ch == PORT).sum() == (ch == STARBOARD).sum() > 0:     # both channels: one nadir per ping
        both = np.fmin(out[ch == PORT], out[ch == STARBOARD])
        out[ch == PORT], out[ch == STARBOARD] = both, both
    return out


def across_track(scan) -> np.ndarray:
    """(n_rows, 3) horizontal unit vector of each row pointing across the track to its side: the
    horizontal part of the boresight (a channel looking straight down has none: refused)."""
    u = scan.poses[:, :3, 2].copy()
    u[:, 2] = 0.0
    n = np.linalg.norm(u, axis=1)
    if (n < 1e-9).any():
        raise ValueError("ground_range: a row's boresight is vertical (depression 90 deg): it has no side "
                         "to place ground ranges on")
    return u / n[:, None]


@dataclass
class GroundRange:
    """A side-scan scan resampled on ground range.

    ``values`` (n_rows, n_ground): the row's value (``use``) at each ground range, NaN where no echo
    can come from (the nadir gap, beyond the range window); ``ground`` (n_ground,) the ground-range
    sample positions (m across the track from the transducer's vertical); ``altitude`` (n_rows,)
    the altitude used for each row (the flat-bottom correction) or the head's height above the
    seabed under it (a known seabed)."""

    values: np.ndarray
    ground: np.ndarray
    altitude: np.ndarray


def ground_range(scan, resolution=None, ground_max=None, altitude=None, seabed=None, use="intensity",
                 threshold=1e-3) -> GroundRange:
    """Slant-range to ground-range correction of a side-scan ``scan`` (the module's formulas).

    =========== ==================================================================================
    resolution  m between ground samples (default: the scan's bin width)
    ground_max  m, the farthest ground range (default: ``range_max`` across a flat bottom)
    altitude    m above a flat bottom: one number, or one per row; default the measured altitude,
                `first_return` (``threshold``) of each row
    seabed      a known seabed instead of a flat one: ``seabed(x, y) -> z`` (world, vectorised;
                a `mitsonar.scenes.terrain.Terrain`'s ``height`` or `seabed_from_mesh`)
    use         ``intensity`` (noise-free energy per bin) or ``data`` (device bytes)
    =========== ==================================================================================

    Each ground sample takes the value of the slant-range bin it falls in (no interpolation: an
    echo or a shadow keeps its edges).
    """
    _check_sidescan(scan, "ground_range")
    v = _values(scan, use, "ground_range")
    if altitude is not None and seabed is not None:
        raise ValueError("ground_range: give 'altitude' (a flat bottom) or 'seabed' (a known one), not both")
    res = scan.bin_width if resolution is None else float(resolution)
    if not (np.isfinite(res) and res > 0):
        raise ValueError(f"ground_range 'resolution': {resolution!r} is not allowed (m > 0)")
    top = scan.range_max if ground_max is None else float(ground_max)
    if not (np.isfinite(top) and top > 0):
        raise ValueError(f"ground_range 'ground_max': {ground_max!r} is not allowed (m > 0)")
    n_rows = scan.n_pings
    g = (np.arange(int(np.ceil(top / res))) + 0.5) * res
    pos = scan.poses[:, :3, 3]
    if seabed is not None:
        if not callable(seabed):
            seabed = getattr(seabed, "height", None)
            if seabed is None:
                raise ValueError("ground_range 'seabed': expected a callable seabed(x, y) -> z or an object "
                                 "with .height(x, y), such as a mitsonar.scenes.terrain.Terrain")
        u = across_track(scan)
        q = pos[:, None, :] + g[None, :, None] * u[:, None, :]
        z = np.asarray(seabed(q[..., 0], q[..., 1]), dtype=np.float64).reshape(n_rows, len(g))
        depth = pos[:, 2:3] - z
        slant = np.sqrt(g[None, :] ** 2 + depth ** 2)
        alt = np.asarray(seabed(pos[:, 0], pos[:, 1]), dtype=np.float64).reshape(n_rows)
        alt = pos[:, 2] - alt
    else:
        if altitude is None:
            alt = first_return(scan, threshold, "intensity" if np.any(scan.intensity) else "data")
        else:
            alt = np.broadcast_to(np.asarray(altitude, dtype=np.float64), (n_rows,)).copy()
            if not (np.isfinite(alt).all() and (alt >= 0).all()):
                raise ValueError(f"ground_range 'altitude': {altitude!r} is not allowed (m >= 0, one or one per row)")
        slant = np.sqrt(g[None, :] ** 2 + alt[:, None] ** 2)
    k = np.floor((slant - scan.range_min) / scan.bin_width)
    ok = np.isfinite(k) & (k >= 0) & (k < scan.n_bins)
    out = np.full((n_rows, len(g)), np.nan)
    rows = np.broadcast_to(np.arange(n_rows)[:, None], k.shape)
    out[ok] = v[rows[ok], k[ok].astype(np.int64)]
    return GroundRange(values=out, ground=g, altitude=alt)


def waterfall(scan, use="data", ground=None) -> np.ndarray:
    """The waterfall picture's array of a side-scan ``scan``: (n_pings, 2 n_cols), the port channel
    mirrored on the left (range growing leftwards from the centre), the starboard channel on the
    right, the newest ping on the top row (as side-scan viewers scroll). ``n_cols`` is the scan's
    bins, or the ground samples of ``ground`` (a `GroundRange` of this scan). A side the scan does
    not have is NaN.

    Pixel of an echo of ping ``k`` at bin (or ground sample) ``j``: row ``n_pings - 1 - k``,
    column ``n_cols - 1 - j`` on port, ``n_cols + j`` on starboard."""
    _check_sidescan(scan, "waterfall")
    v = _values(scan, use, "waterfall") if ground is None else np.asarray(ground.values, dtype=np.float64)
    if v.shape[0] != scan.n_pings:
        raise ValueError(f"waterfall 'ground': {v.shape[0]} rows, the scan has {scan.n_pings}")
    n_cols = v.shape[1]
    ch = scan.channel
    n_pings = int(np.bincount(ch, minlength=2).max())
    out = np.full((n_pings, 2 * n_cols), np.nan)
    for c, cols in ((PORT, slice(n_cols - 1, None, -1)), (STARBOARD, slice(None))):
        rows = np.flatnonzero(ch == c)
        if len(rows):
            block = v[rows][::-1]              # newest first
            if c == PORT:
                out[:, :n_cols] = block[:, cols]
            else:
                out[:, n_cols:] = block
    return out


def seabed_from_mesh(vertices, faces=None):
    """A seabed ``f(x, y) -> z`` from a height-field mesh (vertices (N, 3), e.g. a terrain PLY or one
    shape of `mitsonar.scene_mesh`): linear over the Delaunay triangles of the vertices' x-y,
    NaN outside them. ``faces`` is accepted for symmetry with the scene meshes and not needed."""
    from scipy.interpolate import LinearNDInterpolator

    v = np.asarray(vertices, dtype=np.float64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 3:
        raise ValueError(f"seabed_from_mesh: expected (N >= 3, 3) vertices, got shape {v.shape}")
    interp = LinearNDInterpolator(v[:, :2], v[:, 2])

    def height(x, y):
        x, y = np.broadcast_arrays(np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64))
        return interp(np.stack([x.ravel(), y.ravel()], axis=1)).reshape(x.shape)
    return height


def seabed_of_scene(scene, shape_id="seabed"):
    """`seabed_from_mesh` of the mesh shape ``shape_id`` of a loaded scene (its vertices in world
    coordinates; without one, of its meshes ``<shape_id>_*`` together: a seabed of several materials): the scene's known seabed for `ground_range` and `mitsonar.products.mosaic.mosaic`."""
    import mitsuba as mi

    shapes = [s for s in scene.shapes() if s.id() == shape_id]
    # a seabed of several materials (`mitsonar.scenes.grid`'s sediments): its parts, ``seabed_<material>``
    shapes = shapes or [s for s in scene.shapes() if s.id().startswith(shape_id + "_") and isinstance(s, mi.Mesh)]
    for shape in shapes:
        if not isinstance(shape, mi.Mesh):
            raise ValueError(f"seabed_of_scene: shape {shape_id!r} is not a mesh (a height field is needed)")
    if shapes:
        return seabed_from_mesh(np.concatenate([np.array(s.vertex_positions_buffer(), dtype=np.float64).reshape(-1, 3)
                                                for s in shapes]))
    ids = ", ".join(repr(s.id()) for s in scene.shapes())
    raise ValueError(f"seabed_of_scene: the scene has no shape {shape_id!r} (its shapes: {ids})")
