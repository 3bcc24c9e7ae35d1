"""Surfaces and cross-sections of a fitted Hilbert map: the level and ridge extractors, slices.

Every function takes a fitted :class:`~hilbertmap.HilbertMap` and only queries it (it reads its
learnt state and calls ``decision_function``, ``predict_proba``, ``seen``); nothing is stored on
the map. Extracting several surfaces from one grid: sample it once with :func:`sample_grid` and
pass it as ``grid=`` to each extractor.

- Level surface: the ``p = level`` isosurface by marching tetrahedra (:mod:`hilbertmap.mesh`) on
  a regular grid of probabilities.
- Ridge surface: the level surface's vertices moved uphill along ``grad p`` onto the wall's face
  (thesis 4.4: the surface is where the occupancy rises, seen from the free side).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ._checks import MAX_GRID_POINTS  # noqa: F401  (re-exported: the most points a grid may hold)
from ._checks import axis_index, check_bounds, fitting_resolution, grid_axes, grid_shape, need, num_param
from .mesh import marching_tetrahedra
from .sgd import sigmoid


class MapSlice:
    """A planar cross-section: ``prob[iv, iu]`` at ``(u[iu], v[iv])`` on the plane ``axis = value``."""

    def __init__(self, prob, seen, u, v, axis, value, axes):
        self.prob, self.seen, self.u, self.v = prob, seen, u, v
        self.axis, self.value, self.axes = axis, value, axes

    @property
    def extent(self):
        """(u_min, u_max, v_min, v_max) for ``imshow(..., origin='lower')``."""
        du = self.u[1] - self.u[0] if len(self.u) > 1 else 1.0
        dv = self.v[1] - self.v[0] if len(self.v) > 1 else 1.0
        return (self.u[0] - du / 2, self.u[-1] + du / 2, self.v[0] - dv / 2, self.v[-1] + dv / 2)

    def __iter__(self):  # prob, extent = hm.slice(...)
        return iter((self.prob, self.extent))


@dataclass(frozen=True)
class GridSample:
    """Probabilities ``prob[i, j, k]`` of a map at ``(axes[0][i], axes[1][j], axes[2][k])``."""

    axes: list
    prob: np.ndarray
    resolution: float


def cross_section(hm, axis="z", value: float = 0.0, extent=None, resolution: float = 0.05) -> MapSlice:
    """Probability on the plane ``axis = value`` (see :meth:`HilbertMap.slice`)."""
    hm._check_fitted()
    a = axis_index(axis)
    others = [i for i in range(3) if i != a]
    num_param("value", value)
    num_param("resolution", resolution, 0, lo_open=True)
    if extent is None:
        lo, hi = hm.coverage_.bounds()
        extent = ((lo[others[0]], hi[others[0]]), (lo[others[1]], hi[others[1]]))
    try:
        ext = np.asarray(extent, dtype=np.float64)
    except (TypeError, ValueError):
        ext = None
    uv = "xyz"[others[0]] + ", " + "xyz"[others[1]]
    need("extent", extent, ext is not None and ext.shape == (2, 2) and bool(np.isfinite(ext).all())
         and bool((ext[:, 0] <= ext[:, 1]).all()),
         f"((u_min, u_max), (v_min, v_max)) in metres over {uv}, each min <= max")
    u, v = grid_axes("resolution", resolution, ext[:, 0], ext[:, 1], f"the slice's extent ({uv})")
    U, V = np.meshgrid(u, v, indexing="xy")
    pts = np.zeros((U.size, 3))
    pts[:, others[0]] = U.ravel()
    pts[:, others[1]] = V.ravel()
    pts[:, a] = value
    prob = hm.predict_proba(pts).reshape(U.shape)
    seen = hm.seen(pts).reshape(U.shape)
    return MapSlice(prob=prob, seen=seen, u=u, v=v, axis="xyz"[a], value=float(value),
                    axes=("xyz"[others[0]], "xyz"[others[1]]))


def default_resolution(hm) -> float:
    """The grid step `sample_grid` takes when given none: a quarter of the length-scale, at most
    10 cm and at least 2 cm."""
    return max(min(hm.lengthscale_ / 4.0, 0.1), 0.02)


def mesh_resolution(hm, max_points: int, bounds=None) -> tuple:
    """``(resolution, default, points)``: `default_resolution` when its grid over ``bounds``
    (default the region seen) holds at most ``max_points`` points (`points`: how many it holds),
    else the finest coarser step that does (`fitting_resolution`), for a mesh that a caller wants
    made rather than refused."""
    hm._check_fitted()
    lo, hi = hm.coverage_.bounds() if bounds is None else check_bounds("bounds", bounds, none=False)
    default = default_resolution(hm)
    points = 1
    for n in grid_shape(default, lo, hi):
        points *= n
    return fitting_resolution(default, lo, hi, max_points), default, points


def sample_grid(hm, resolution: float | None = None, bounds=None) -> GridSample:
    """The map's probabilities on a grid of ``resolution`` metres over ``bounds``.

    ``resolution`` defaults to a quarter of the length-scale, at most 10 cm and at least 2 cm;
    ``bounds`` ``(lo, hi)`` default to the region seen. At most ``MAX_GRID_POINTS`` points in all:
    a finer grid is refused before it is allocated, naming a resolution that fits.
    """
    hm._check_fitted()
    if bounds is None:
        lo, hi = hm.coverage_.bounds()
        where = "the region seen"
    else:
        lo, hi = check_bounds("bounds", bounds, none=False)
        where = "the bounds"
    num_param("resolution", resolution, 0, lo_open=True, special=(None,))
    if resolution is None:
        resolution = default_resolution(hm)
    axes = grid_axes("resolution", resolution, lo, hi, where)
    X, Y, Z = np.meshgrid(*axes, indexing="ij")
    pts = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
    return GridSample(axes=axes, prob=hm.predict_proba(pts).reshape(X.shape), resolution=float(resolution))


def isosurface(hm, level: float = 0.5, resolution: float | None = None, bounds=None, only_seen: bool = True,
               grid: GridSample | None = None):
    """Triangle mesh (vertices (V, 3), faces (F, 3)) of the ``p = level`` surface.

    Sampled by :func:`sample_grid` (``resolution``, ``bounds``) unless ``grid`` is given (then
    those two are not used); ``level`` lies in (0, 1). With ``only_seen`` faces outside the region
    seen are dropped (behind walls the map has no data and sits at its prior).
    """
    hm._check_fitted()
    # p lies in (0, 1): any other level has no surface, and an empty mesh would hide the slip
    num_param("level", level, 0, 1, lo_open=True, hi_open=True)
    if grid is None:
        grid = sample_grid(hm, resolution, bounds)
    V, Fc = marching_tetrahedra(grid.prob, grid.axes, level)
    if only_seen and len(Fc):
        cen = V[Fc].mean(axis=1)
        keep = hm.seen(cen, dilate=1)
        V, Fc = compact(V, Fc[keep])
    return V, Fc


def ridge_surface(hm, resolution: float | None = None, bounds=None, level: float = 0.5,
                  max_shift: float | None = None, only_seen: bool = True, plateau: float | None = 0.1,
                  front_only: bool = True, grid: GridSample | None = None):
    """Triangle mesh on the probability ridge: the wall as seen from the free side.

    The ``level`` isosurface is extracted, then every vertex ``x`` moves along
    ``n = grad f / |grad f|`` (``f`` the logit, central differences), at most ``max_shift``
    (default 1.5 length-scales). A wall's evidence is one-sided: free space in front, and behind it
    the acoustic shadow, where nothing pulls p down. So p rises across the wall's face and then
    stays on a plateau that reaches into the shadow, and its maximum drifts behind the wall, the
    further the sharper the free side is learnt. A vertex therefore stops where p first comes
    within ``plateau`` of the largest p on its line (:func:`plateau_step`; ``None``: at the
    maximum itself, the classical ridge, refined by a parabola through the three samples around
    it). With ``front_only`` the faces on the shadow side of the plateau are dropped: those whose
    low side (`FRONT_DEPTH`, 0.1 m downhill from the level) was never seen empty (:func:`in_front`: neither a
    free sample in its voxel nor inside the free part of a ping's frustum).
    """
    V, Fc = isosurface(hm, level=level, resolution=resolution, bounds=bounds, only_seen=only_seen, grid=grid)
    if len(V) == 0:
        return V, Fc
    step = max_shift if max_shift is not None else 1.5 * hm.lengthscale_
    h = 0.25 * min(hm.lengthscale_, 0.2)
    offs = np.eye(3) * h
    grad = np.stack([(hm.decision_function(V + o) - hm.decision_function(V - o)) / (2 * h) for o in offs], axis=1)
    n = grad / np.maximum(np.linalg.norm(grad, axis=1, keepdims=True), 1e-12)
    if front_only:
        # decided on the level's vertices and normals, so the lines below are only sampled for
        # the faces that stay (about half of them in the thesis box)
        front = in_front(hm, V, n)
        keep = front[Fc].all(axis=1)
        if keep.any():
            used = np.unique(Fc[keep])
            V, n, Fc = V[used], n[used], compact(V, Fc[keep])[1]
    ts = np.linspace(0.0, step, 25)
    pts = V[:, None, :] + ts[None, :, None] * n[:, None, :]
    f = hm.decision_function(pts.reshape(-1, 3)).reshape(len(V), len(ts))
    rows = np.arange(len(V))
    k = np.argmax(f, axis=1)
    if plateau is None:
        # parabolic refinement around the discrete maximum
        k0 = np.clip(k, 1, len(ts) - 2)
        fm, f0, fp = f[rows, k0 - 1], f[rows, k0], f[rows, k0 + 1]
        den = fm - 2 * f0 + fp
        delta = np.where((den < 0) & (k == k0), 0.5 * (fm - fp) / np.where(den < 0, den, -1), 0.0)
        t = ts[k0] + np.clip(delta, -1, 1) * (ts[1] - ts[0])
        t = np.where(k == k0, t, ts[k])
    else:
        t = plateau_step(f, ts, plateau)
    return V + t[:, None] * n, Fc


def surface(hm, method: str = "ridge", **kw):
    """``method='ridge'`` (:func:`ridge_surface`) or ``'level'`` (:func:`isosurface`)."""
    if method == "ridge":
        return ridge_surface(hm, **kw)
    if method in ("level", "iso", "isosurface"):
        return isosurface(hm, **kw)
    raise ValueError(f"HilbertMap: surface method must be 'ridge' or 'level', not {method!r}")


def free_coverage(hm):
    """The voxels holding free samples (maps saved before that record existed: all voxels seen)."""
    return getattr(hm, "free_coverage_", None) or hm.coverage_


#: How far downhill (against the map's gradient, metres) a surface point's low side is tested for
#: having been seen empty: the front rule of the ridge surface and of the slice metrics' ridge.
FRONT_DEPTH = 0.1


def in_front(hm, points, normals) -> np.ndarray:
    """Whether each point's low side, `FRONT_DEPTH` downhill along its unit normal (the map's
    gradient direction), was seen empty (:func:`seen_empty`): the point faces observed water."""
    return seen_empty(hm, np.asarray(points) - FRONT_DEPTH * np.asarray(normals))


#: at most this many (ping, point) pairs are tested by :func:`seen_empty` (about 10 s); beyond it
#: the free-sample voxels alone decide
SEEN_EMPTY_BUDGET = 2e8


def seen_empty(hm, points, chunk: int = 64) -> np.ndarray:
    """Whether each point was seen empty: it lies in a voxel holding free samples, or in the free
    part of the nominal frustum of a training ping with an echo (inside the -3 dB widths, between
    where the ping's free part starts and its first echo).

    The voxels alone miss water that the pings crossed without leaving a sample in that voxel
    (free samples are drawn at random, about one per ping in a 0.25 m voxel 5 m away), and the
    ridge then lost its faces there: holes up to 0.6 m across in the thesis box's walls. The
    frusta are what the pings saw; they are tested (numpy, ``chunk`` pings at a time) for the
    points the voxels leave out next to a voxel that holds free samples (water crossed by a ping
    is next to some sample), only when the map still holds its ping records and the test costs at
    most ``SEEN_EMPTY_BUDGET`` (ping, point) pairs.
    """
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    cov = free_coverage(hm)
    out = cov.contains(P)
    frames = getattr(hm, "ping_frames_", None)
    if frames is None or len(frames) == 0 or out.all():
        return out
    # water a ping crossed has free samples in a neighbouring voxel: only those points are tested
    rest = np.nonzero(~out & cov.contains(P, dilate=1))[0]
    if len(frames) * len(rest) > SEEN_EMPTY_BUDGET or hm.ping_spans_ is None:
        return out
    spans = np.asarray(hm.ping_spans_, dtype=np.float64)
    # pings with an echo only: a ping whose echo was missed (a weak oblique wall) would call the
    # water behind the wall seen, and keep the faces on the shadow side of the band
    echo = np.isfinite(spans[:, 1])
    frames = np.asarray(frames, dtype=np.float64)[echo]
    beams = np.asarray(hm.ping_beams_, dtype=np.float64)[echo]
    spans = spans[echo]
    tan_h = np.tan(np.radians(np.minimum(beams[:, 0], 179.0)) / 2)
    sin_v = np.sin(np.radians(np.minimum(beams[:, 1], 180.0)) / 2)
    start = spans[:, 0]
    end = spans[:, 1]
    for a in range(0, len(frames), int(chunk)):
        if len(rest) == 0:
            break
        b = min(a + int(chunk), len(frames))
        R, o = frames[a:b, :3, :3], frames[a:b, :3, 3]
        # beam-frame coordinates of every remaining point for each ping of the chunk, one matrix
        # product: x[n, c] = (p_n - o_c) . R_c[:, 0], and likewise y and z
        cols = R.transpose(1, 2, 0)  # (3, 3, c): cols[:, j, c] = R_c[:, j]
        off = np.einsum("ci,cij->jc", o, R)  # (3, c): o_c . R_c[:, j]
        Q = P[rest]
        x, y, z = (Q @ cols[:, j, :] - off[j] for j in range(3))
        r = np.sqrt(x * x + y * y + z * z)
        # |azimuth| = |atan2(x, z)| <= bw_h / 2 and |elevation| = |asin(y / r)| <= bw_v / 2
        inside = ((z > 0) & (np.abs(x) <= z * tan_h[a:b]) & (np.abs(y) <= r * sin_v[a:b])
                  & (r >= start[a:b]) & (r < end[a:b]))
        hit = inside.any(axis=1)
        out[rest[hit]] = True
        rest = rest[~hit]
    return out


def plateau_step(f: np.ndarray, ts: np.ndarray, plateau: float) -> np.ndarray:
    """Per row of logits ``f`` sampled at steps ``ts``: the step where ``p = sigmoid(f)`` first
    comes within ``plateau`` of the row's largest p (linearly interpolated)."""
    p = sigmoid(f)
    rows = np.arange(len(f))
    target = p.max(axis=1) - float(plateau)
    k1 = np.argmax(p >= target[:, None], axis=1)
    km = np.maximum(k1 - 1, 0)
    lo_p, hi_p = p[rows, km], p[rows, k1]
    frac = np.where(hi_p > lo_p, np.clip((target - lo_p) / np.maximum(hi_p - lo_p, 1e-12), 0, 1), 1.0)
    return np.where(k1 > 0, ts[km] + frac * (ts[k1] - ts[km]), ts[0])


def compact(V, F):
    """Drop the vertices no face uses and renumber the faces."""
    used = np.unique(F)
    remap = np.full(len(V), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return V[used], remap[F]
