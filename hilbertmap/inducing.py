"""Inducing points of the Nystroem approximation, and the voxel set of the region the sonar saw."""
from __future__ import annotations

import numpy as np

METHODS = ("kmeans", "grid", "random", "samples")


def sorted_unique(a: np.ndarray) -> np.ndarray:
    """``np.unique`` of a 1-D integer array by a sort (NumPy 2.4's ``unique`` hashes int64 keys
    and is 30 times slower on a million of them)."""
    a = np.sort(np.asarray(a).ravel())
    if len(a) < 2:
        return a
    return a[np.r_[True, a[1:] != a[:-1]]]


class Coverage:
    """Sparse set of voxels (side ``voxel``) that hold at least one training sample."""

    def __init__(self, voxel: float, keys: np.ndarray | None = None):
        self.voxel = float(voxel)
        self.keys = sorted_unique(np.asarray(keys if keys is not None else np.zeros(0), dtype=np.int64))

    OFFSET = 1 << 20  # voxel indices in [-2^20, 2^20) per axis

    def _key(self, idx: np.ndarray) -> np.ndarray:
        i = idx.astype(np.int64) + self.OFFSET
        return (i[:, 0] << 42) | (i[:, 1] << 21) | i[:, 2]

    def _idx(self, keys: np.ndarray) -> np.ndarray:
        m = (1 << 21) - 1
        return np.stack([(keys >> 42) & m, (keys >> 21) & m, keys & m], axis=1) - self.OFFSET

    def add(self, points: np.ndarray) -> None:
        if len(points) == 0:
            return
        idx = np.floor(np.asarray(points, dtype=np.float64) / self.voxel).astype(np.int64)
        self.keys = sorted_unique(np.concatenate([self.keys, self._key(idx)]))

    def contains(self, points: np.ndarray, dilate: int = 0) -> np.ndarray:
        """Whether each point lies in a covered voxel (or within ``dilate`` voxels of one)."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        if len(self.keys) == 0:
            return np.zeros(len(pts), dtype=bool)
        idx = np.floor(pts / self.voxel).astype(np.int64)
        out = np.zeros(len(pts), dtype=bool)
        r = range(-dilate, dilate + 1)
        for dx in r:
            for dy in r:
                for dz in r:
                    k = self._key(idx + np.array([dx, dy, dz]))
                    pos = np.searchsorted(self.keys, k)
                    pos = np.minimum(pos, len(self.keys) - 1)
                    out |= self.keys[pos] == k
        return out

    def centres(self) -> np.ndarray:
        return (self._idx(self.keys) + 0.5) * self.voxel

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        idx = self._idx(self.keys)
        return idx.min(axis=0) * self.voxel, (idx.max(axis=0) + 1) * self.voxel

    @property
    def volume(self) -> float:
        return len(self.keys) * self.voxel ** 3


class LazyCoverage(Coverage):
    """A :class:`Coverage` whose additions are merged when it is read, or once they outnumber the
    keys held: a survey adds a scan's voxels many times a second, and merging each into a sorted
    set of millions would cost more than the scan's learning."""

    def __init__(self, voxel, keys=None):
        self._pending = []
        self._n_pending = 0
        super().__init__(voxel, keys)

    @property
    def keys(self):
        if self._pending:
            self._keys = sorted_unique(np.concatenate([self._keys] + self._pending))
            self._pending, self._n_pending = [], 0
        return self._keys

    @keys.setter
    def keys(self, value):
        self._keys = value
        self._pending, self._n_pending = [], 0

    def add(self, points) -> None:
        if len(points) == 0:
            return
        k = sorted_unique(self._key(np.floor(np.asarray(points, dtype=np.float64) / self.voxel).astype(np.int64)))
        self._pending.append(k)
        self._n_pending += len(k)
        if self._n_pending > max(len(self._keys), 1 << 16):
            _ = self.keys


def choose_inducing(method: str, n: int, free: np.ndarray, occupied: np.ndarray, coverage: Coverage,
                    rng: np.random.Generator, occupied_share: float = 0.5, kmeans_iter: int = 10,
                    kmeans_points: int = 60000, dedup: float = 0.0) -> np.ndarray:
    """(n, 3) inducing points.

    ``kmeans``  Lloyd's k-means centres of a subsample of the training points, ``occupied_share`` of
                them drawn from the occupied samples (surfaces get finer features), the rest free
    ``grid``    a regular lattice over the covered voxels, spacing chosen to give about n points
    ``random``  uniform random points in the covered voxels
    ``samples`` a random subset of the training points (free samples and the points of full bins
                alike, as scikit-learn's ``Nystroem`` picks its components)
    """
    if method not in METHODS:
        raise ValueError(f"HilbertMap: unknown inducing method {method!r}; choose one of {', '.join(METHODS)}")
    n = int(n)
    if n < 1:
        raise ValueError("HilbertMap: n_inducing must be at least 1")
    if method == "random":
        c = coverage.centres()
        pick = c[rng.integers(0, len(c), n)]
        return pick + rng.uniform(-0.5, 0.5, (n, 3)) * coverage.voxel
    if method == "grid":
        return _grid(n, coverage)
    if method == "samples":
        pts = np.concatenate([free, occupied.reshape(-1, 3)])
        if len(pts) < n:
            raise ValueError(f"HilbertMap: {len(pts)} samples cannot give {n} inducing points")
        return pts[rng.choice(len(pts), n, replace=False)]
    # k-means
    occ = occupied.reshape(-1, 3)
    if dedup:
        occ, free = _one_per_voxel(occ, dedup, rng), _one_per_voxel(free, dedup, rng)
    n_occ = int(round(kmeans_points * occupied_share)) if len(occ) else 0
    n_occ = min(n_occ, len(occ))
    n_free = min(kmeans_points - n_occ, len(free))
    pts = np.concatenate([
        occ[rng.choice(len(occ), n_occ, replace=False)] if n_occ else np.zeros((0, 3)),
        free[rng.choice(len(free), n_free, replace=False)] if n_free else np.zeros((0, 3)),
    ])
    if len(pts) <= n:
        extra = choose_inducing("random", n - len(pts), free, occupied, coverage, rng) if n > len(pts) else np.zeros((0, 3))
        return np.concatenate([pts, extra])
    return kmeans(pts, n, rng, kmeans_iter)


def kmeans(pts: np.ndarray, k: int, rng: np.random.Generator, n_iter: int = 10) -> np.ndarray:
    """Lloyd's algorithm from a random subset; empty clusters re-seeded at random points."""
    from scipy.spatial import cKDTree

    from ._threads import interruptible

    centres = pts[rng.choice(len(pts), k, replace=False)].copy()
    for _ in range(n_iter):
        # its threads joined in a worker: a Ctrl-C must not unwind the query under them
        _, lab = interruptible(cKDTree(centres).query, pts, workers=-1)
        cnt = np.bincount(lab, minlength=k).astype(np.float64)
        sums = np.zeros((k, 3))
        for a in range(3):
            sums[:, a] = np.bincount(lab, weights=pts[:, a], minlength=k)
        empty = cnt == 0
        centres[~empty] = sums[~empty] / cnt[~empty, None]
        if empty.any():
            centres[empty] = pts[rng.choice(len(pts), int(empty.sum()), replace=False)]
    return centres


def _grid(n: int, coverage: Coverage) -> np.ndarray:
    lo, hi = coverage.bounds()
    vol = max(coverage.volume, 1e-9)
    s = (vol / n) ** (1.0 / 3.0)
    best = None
    for _ in range(30):
        axes = [np.arange(lo[a] + 0.5 * s, hi[a], s) for a in range(3)]
        g = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        g = g[coverage.contains(g, dilate=0)]
        if best is None or abs(len(g) - n) < abs(len(best) - n):
            best = g
        if len(g) == 0:
            s *= 0.8
            continue
        ratio = len(g) / n
        if abs(ratio - 1) < 0.02:
            break
        s *= ratio ** (1.0 / 3.0)
    return best


def spacing(points: np.ndarray) -> float:
    """Median distance from an inducing point to its nearest neighbour."""
    from scipy.spatial import cKDTree

    if len(points) < 2:
        return 1.0
    d, _ = cKDTree(points).query(points, k=2)
    return float(np.median(d[:, 1]))


def _one_per_voxel(pts: np.ndarray, voxel: float, rng: np.random.Generator) -> np.ndarray:
    """One random point of each occupied voxel: k-means then follows the area seen, not the
    number of pings that saw it."""
    if len(pts) == 0:
        return pts
    perm = rng.permutation(len(pts))
    idx = np.floor(pts[perm] / voxel).astype(np.int64)
    _, first = np.unique(idx, axis=0, return_index=True)
    return pts[perm[np.sort(first)]]
