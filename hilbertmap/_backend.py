"""Dr.Jit kernels of the Hilbert map: RBF sums and their adjoint over a uniform cell grid.

The map's logit is ``f(x) = sum_j a_j k(x, nu_j) + b`` with an RBF kernel ``k`` that is cut to
zero below ``kernel_cut`` (so its support is a ball of radius ``r_cut``). The inducing points
``nu_j`` are binned into cubic cells of side ``r_cut / CELL_DIV``; a lane visits the
``(2 CELL_DIV + 1)^3`` cells around its point in one symbolic loop whose every iteration either
processes one inducing point or moves on to the next cell. Kernel values under the cut are never
formed, so no denormal reaches any product.

Two kernels share the loop: ``kernel_sum`` (lane -> sum_j c_j k(x, nu_j)) and ``kernel_scatter``
(``out[j] += g_lane k(x_lane, nu_j)``, the adjoint, used for the SGD gradient).
"""
from __future__ import annotations

import math

import numpy as np

import drjit as dr

CELL_DIV = 2  # cells per cut radius; 2 visits 125 cells of (r/2)^3: measured fastest of 1, 2, 3


def _variant(name: str):
    if name == "llvm":
        import drjit.llvm as mod
    elif name == "cuda":
        import drjit.cuda as mod
    else:
        raise ValueError(f"HilbertMap: unknown Dr.Jit variant {name!r} (use 'llvm' or 'cuda')")
    return mod


def upload(jit_type, values, dtype=np.float32):
    """``jit_type`` holding ``values`` (flat), in memory aligned to 256 bytes.

    Dr.Jit maps a NumPy array instead of copying it and compiles the kernels that read it for the
    pointer's alignment (a whole vector or none), which NumPy leaves to chance: every batch of a
    fit could then meet a kernel compiled anew. (mitsonar's plugins do the same; this package
    does not import mitsonar.)"""
    a = np.asarray(values, dtype=dtype).ravel()
    buf = np.empty(a.nbytes + 256, dtype=np.uint8)
    start = -buf.ctypes.data % 256
    out = buf[start:start + a.nbytes].view(dtype)
    out[:] = a
    arr = jit_type(out)
    dr.make_opaque(arr)  # one element would otherwise be baked into the kernel as a literal
    return arr


def cut_radius(lengthscale: float, kernel_cut: float) -> float:
    """Distance at which ``exp(-d^2 / (2 l^2))`` falls to ``kernel_cut``."""
    return float(lengthscale * math.sqrt(2.0 * math.log(1.0 / kernel_cut)))


class KernelGrid:
    """Inducing points binned into a cell grid, held as Dr.Jit arrays of one variant.

    ``order`` maps the grid's (cell-sorted) index back to the caller's inducing-point index:
    the grid stores point ``order[i]`` at position ``i``.
    """

    def __init__(self, points: np.ndarray, lengthscale: float, kernel_cut: float, variant: str = "llvm"):
        mod = _variant(variant)
        self.mod = mod
        self.Float, self.UInt32, self.Int32 = mod.Float, mod.UInt32, mod.Int32
        pts = np.asarray(points, dtype=np.float64)
        self.n = len(pts)
        self.lengthscale = float(lengthscale)
        self.kernel_cut = float(kernel_cut)
        self.r_cut = cut_radius(lengthscale, kernel_cut)
        self.h = self.r_cut / CELL_DIV
        self.lo = pts.min(axis=0) - 1e-3
        self.dims = np.maximum(np.ceil((pts.max(axis=0) + 1e-3 - self.lo) / self.h).astype(np.int64), 1)
        cell = np.floor((pts - self.lo) / self.h).astype(np.int64)
        cell = np.minimum(cell, self.dims - 1)
        lin = (cell[:, 0] * self.dims[1] + cell[:, 1]) * self.dims[2] + cell[:, 2]
        self.order = np.argsort(lin, kind="stable")
        lin = lin[self.order]
        # first point of every cell (points sorted by cell): a prefix sum of the cell counts
        self.cell_counts = np.bincount(lin, minlength=int(np.prod(self.dims)))
        start = np.zeros(len(self.cell_counts) + 1, dtype=np.uint32)
        np.cumsum(self.cell_counts, out=start[1:])
        sp = pts[self.order].astype(np.float32)
        self.px, self.py, self.pz = (self.upload(sp[:, c]) for c in range(3))
        self.cell_start = upload(self.UInt32, start, np.uint32)
        self._gamma = 1.0 / (2.0 * self.lengthscale ** 2)
        self.inv_order = np.empty_like(self.order)
        self.inv_order[self.order] = np.arange(self.n)

    # -- helpers -----------------------------------------------------------------------------
    def cell_keys(self, pts: np.ndarray) -> np.ndarray:
        """Linear cell index of world points (clamped), to sort lanes for cache locality."""
        c = np.floor((np.asarray(pts, dtype=np.float64) - self.lo) / self.h).astype(np.int64)
        c = np.clip(c, 0, self.dims - 1)
        return (c[:, 0] * self.dims[1] + c[:, 1]) * self.dims[2] + c[:, 2]

    def upload(self, values) -> "Float":
        """A float32 Dr.Jit array of this grid's variant (see `upload`)."""
        return upload(self.Float, values, np.float32)

    def to_lanes(self, pts: np.ndarray):
        p = np.asarray(pts, dtype=np.float32)
        return self.upload(p[:, 0]), self.upload(p[:, 1]), self.upload(p[:, 2])

    def _loop(self, x, y, z, coef=None, g=None, out=None):
        Float, UInt32, Int32 = self.Float, self.UInt32, self.Int32
        R = CELL_DIV
        W = 2 * R + 1
        inv_h = dr.opaque(Float, 1.0 / self.h)
        lox, loy, loz = (dr.opaque(Float, float(v)) for v in self.lo)
        gamma = dr.opaque(Float, self._gamma)
        rc2 = dr.opaque(Float, self.r_cut ** 2)
        D0, D1, D2 = (dr.opaque(Int32, int(v)) for v in self.dims)
        px, py, pz, cs = self.px, self.py, self.pz, self.cell_start
        cx = Int32(dr.floor((x - lox) * inv_h))
        cy = Int32(dr.floor((y - loy) * inv_h))
        cz = Int32(dr.floor((z - loz) * inv_h))
        q = dr.zeros(UInt32, dr.width(x))
        j = dr.zeros(UInt32, dr.width(x))
        je = dr.zeros(UInt32, dr.width(x))
        acc = dr.zeros(Float, dr.width(x))
        ncell = W ** 3

        def cond(q, j, je, acc):
            return (q < ncell) | (j < je)

        def body(q, j, je, acc):
            has = j < je
            nx = dr.gather(Float, px, j, has)
            ny = dr.gather(Float, py, j, has)
            nz = dr.gather(Float, pz, j, has)
            d2 = dr.square(x - nx) + dr.square(y - ny) + dr.square(z - nz)
            m = has & (d2 < rc2)
            kv = dr.exp(-gamma * d2)
            if out is None:
                acc = acc + dr.select(m, kv * dr.gather(Float, coef, j, m), 0.0)
            else:
                dr.scatter_add(out, g * kv, j, m, mode=dr.ReduceMode.Local)
            load = ~has
            qi = Int32(q)
            ix = cx + qi // (W * W) - R
            iy = cy + (qi // W) % W - R
            iz = cz + qi % W - R
            inside = load & (ix >= 0) & (iy >= 0) & (iz >= 0) & (ix < D0) & (iy < D1) & (iz < D2)
            cid = UInt32((ix * D1 + iy) * D2 + iz)
            s = dr.gather(UInt32, cs, cid, inside)
            e = dr.gather(UInt32, cs, cid + 1, inside)
            j = dr.select(has, j + 1, s)
            je = dr.select(has, je, e)
            q = dr.select(load, q + 1, q)
            return q, j, je, acc

        q, j, je, acc = dr.while_loop((q, j, je, acc), cond, body, label="hilbertmap_rbf")
        return acc

    # -- public kernels ----------------------------------------------------------------------
    def kernel_sum(self, x, y, z, coef):
        """Lane-wise ``sum_j coef[j] k(x, nu_j)``; ``coef`` in grid order (a Dr.Jit Float)."""
        return self._loop(x, y, z, coef=coef)

    def kernel_sum_at(self, pts: np.ndarray, coef) -> np.ndarray:
        """``sum_j coef[j] k(x, nu_j)`` at (N, 3) world points, float64 in the points' order: the
        points go to the lanes sorted by cell (neighbouring lanes visit the same cells)."""
        order = np.argsort(self.cell_keys(pts), kind="stable")
        x, y, z = self.to_lanes(pts[order])
        res = np.empty(len(pts), dtype=np.float64)
        res[order] = self.kernel_sum(x, y, z, coef).numpy()
        return res

    def kernel_scatter(self, x, y, z, g, out):
        """``out[j] += g * k(x, nu_j)`` for every lane (grid order), through atomics."""
        self._loop(x, y, z, g=g, out=out)
        return out

    def gram(self) -> np.ndarray:
        """Dense float64 Gram matrix of the inducing points, caller's order (numpy)."""
        pts = np.stack([self.px.numpy(), self.py.numpy(), self.pz.numpy()], axis=1).astype(np.float64)
        pts = pts[self.inv_order]
        sq = np.sum(pts * pts, axis=1)
        d2 = np.maximum(sq[:, None] + sq[None, :] - 2.0 * pts @ pts.T, 0.0)
        G = np.exp(-self._gamma * d2)
        G[G < self.kernel_cut] = 0.0  # the same cut as the queries: the approximated kernel is the cut one
        return G
