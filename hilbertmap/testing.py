"""Synthetic scans of the thesis box for tests and examples (numpy only, no renderer).

:func:`box_scan` casts rays inside the semi-infinite box of thesis Table 2.1 (walls x = +-5,
y = +-4, floor z = -3, open top) from a beam frame pose, and returns a :class:`SyntheticScan`
carrying the attributes of ``mitsonar.Scan`` that :mod:`hilbertmap` reads. Echo energy per ray is
``B_tx B_rx cos(incidence) / r^2`` with directions drawn from the two-way gaussian beam pattern;
``data`` follows a Micron-like chain (20 log r TVG, 24 dB window, speckle, ring-down).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

BOX = dict(x=5.0, y=4.0, floor=-3.0, top=30.0)


@dataclass
class SyntheticScan:
    intensity: np.ndarray
    data: np.ndarray
    ranges: np.ndarray
    bearings: np.ndarray
    poses: np.ndarray
    range_min: float
    range_max: float
    beam_pattern: str = "gaussian"
    beamwidth_h: float = 3.0
    beamwidth_v: float = 35.0
    kind: str = "mechanical"
    meta: dict = field(default_factory=dict)

    @property
    def n_pings(self):
        return self.intensity.shape[0]

    @property
    def n_bins(self):
        return self.intensity.shape[1]


def frame(boresight, scan_axis, position=(0.0, 0.0, 0.0)) -> np.ndarray:
    """4x4 beam frame: columns x = y cross z, y = scan axis, z = boresight, and position."""
    z = np.asarray(boresight, dtype=np.float64)
    z = z / np.linalg.norm(z)
    y = np.asarray(scan_axis, dtype=np.float64)
    y = y - z * (y @ z)
    y = y / np.linalg.norm(y)
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = np.cross(y, z), y, z, position
    return T


def orthogonal_frames(position=(0.0, 0.0, 0.0)) -> list[np.ndarray]:
    """The three orthogonal sonar orientations of the thesis: scan axis along z, x and y."""
    return [frame((1, 0, 0), (0, 0, 1), position), frame((0, 1, 0), (1, 0, 0), position),
            frame((1, 0, 0), (0, 1, 0), position)]


def box_distance(points: np.ndarray) -> np.ndarray:
    """Signed distance to the nearest box surface (positive in the water)."""
    p = np.asarray(points, dtype=np.float64)
    return np.minimum.reduce([BOX["x"] - np.abs(p[:, 0]), BOX["y"] - np.abs(p[:, 1]), p[:, 2] - BOX["floor"]])


def box_mesh(top: float = BOX["top"]):
    """(vertices, faces) of the box: floor and four walls up to ``top``, normals into the water."""
    X, Y, Z0 = BOX["x"], BOX["y"], BOX["floor"]
    V = np.array([[-X, -Y, Z0], [X, -Y, Z0], [X, Y, Z0], [-X, Y, Z0],
                  [-X, -Y, top], [X, -Y, top], [X, Y, top], [-X, Y, top]], dtype=np.float64)
    F = np.array([[0, 1, 2], [0, 2, 3],  # floor
                  [0, 4, 5], [0, 5, 1],  # y = -Y
                  [1, 5, 6], [1, 6, 2],  # x = +X
                  [2, 6, 7], [2, 7, 3],  # y = +Y
                  [3, 7, 4], [3, 4, 0]], dtype=np.int64)  # x = -X
    return V, F


def _cast(o, d):
    """Distance and cosine of incidence of rays (o, d) to the inside of the box."""
    t = np.full(len(d), np.inf)
    cosi = np.zeros(len(d))
    for axis, pos in ((0, BOX["x"]), (0, -BOX["x"]), (1, BOX["y"]), (1, -BOX["y"]), (2, BOX["floor"])):
        comp = d[:, axis]
        with np.errstate(divide="ignore", invalid="ignore"):
            ti = (pos - o[axis]) / comp
        ok = (ti > 0) & np.isfinite(ti)
        hit = o[None, :] + ti[:, None] * d
        for other, lim in ((0, BOX["x"]), (1, BOX["y"])):
            if other != axis:
                ok &= np.abs(hit[:, other]) <= lim + 1e-9
        if axis != 2:
            ok &= (hit[:, 2] >= BOX["floor"]) & (hit[:, 2] <= BOX["top"])
        closer = ok & (ti < t)
        t = np.where(closer, ti, t)
        cosi = np.where(closer, np.abs(comp), cosi)
    return t, cosi


def box_scan(pose: np.ndarray, n_pings: int = 200, bearing_step: float = 1.8, n_bins: int = 500,
             range_max: float = 12.0, beamwidth_h: float = 3.0, beamwidth_v: float = 35.0,
             rays: int = 400, noise: bool = True, ringdown: float = 1.3, seed: int = 0) -> SyntheticScan:
    """A mechanical scan of the box from the beam-frame ``pose`` (4x4, bearing 0), or from one
    such pose per ping ((n_pings, 4, 4): a head on a moving vehicle, see :func:`moving_poses`)."""
    rng = np.random.default_rng(seed)
    pose = np.asarray(pose, dtype=np.float64)
    bearings = np.radians(np.arange(n_pings) * bearing_step)
    bw = range_max / n_bins
    ranges = (np.arange(n_bins) + 0.5) * bw
    s_h = math.radians(beamwidth_h) / (4 * math.sqrt(math.log(2)))
    s_v = math.radians(beamwidth_v) / (4 * math.sqrt(math.log(2)))
    intensity = np.zeros((n_pings, n_bins))
    poses = np.empty((n_pings, 4, 4))
    for k, b in enumerate(bearings):
        c, s = math.cos(b), math.sin(b)
        Ry = np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1]])
        P = (pose[k] if pose.ndim == 3 else pose) @ Ry
        poses[k] = P
        az = rng.normal(0, s_h, rays)
        el = rng.normal(0, s_v, rays)
        dl = np.stack([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)], axis=1)
        d = dl @ P[:3, :3].T
        t, cosi = _cast(P[:3, 3], d)
        ok = np.isfinite(t) & (t < range_max)
        e = cosi[ok] / np.maximum(t[ok], 0.1) ** 2 * 5e-4 / rays
        np.add.at(intensity[k], np.minimum((t[ok] / bw).astype(int), n_bins - 1), e)
    level = 10 * np.log10(np.maximum(intensity, 1e-30)) + 80.0 + np.minimum(20 * np.log10(ranges), 40.0)
    power = 10 ** (level / 10)
    if noise:
        power = power * rng.exponential(1.0, power.shape) + 10 ** 1.1 * rng.exponential(1.0, power.shape)
    if ringdown > 0:
        rd_db = 60.0 - (60.0 - 12.5) * ranges / ringdown
        power = power + 10 ** (rd_db / 10)
    data = np.round(255 * np.clip((10 * np.log10(np.maximum(power, 1e-30)) - 12.5) / 24.0, 0, 1)).astype(np.uint8)
    return SyntheticScan(intensity=intensity.astype(np.float32), data=data, ranges=ranges, bearings=bearings,
                         poses=poses, range_min=0.0, range_max=range_max, beamwidth_h=beamwidth_h,
                         beamwidth_v=beamwidth_v, meta=dict(seed=seed, synthetic="box"))


def moving_poses(start, end, n_pings: int = 200, scan_axis=(0.0, 0.0, 1.0), boresight=(1.0, 0.0, 0.0)) -> np.ndarray:
    """(n_pings, 4, 4) bearing-0 beam frames of a head carried at constant speed in a straight line
    from ``start`` to ``end`` (ping k at the fraction k / n_pings of the way), orientation fixed."""
    a, b = np.asarray(start, dtype=np.float64), np.asarray(end, dtype=np.float64)
    f = np.arange(n_pings) / n_pings
    return np.stack([frame(boresight, scan_axis, a + t * (b - a)) for t in f])
