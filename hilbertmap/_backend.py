"""Dr.Jit kernels of the Hilbert map: RBF sums and their adjoint over a uniform cell grid.

The map's logit is ``f(x) = sum_j a_j k(x, nu_j) + b`` with an RBF kernel ``k`` that is cut to
zero below ``kernel_cut`` (so its support is a ball of radius ``r_cut``). The inducing points
``nu_j`` are binned into cubic cells of side ``r_cut / CELL_DIV``; a lane visits the
``(2 CELL_DIV + 1)^3`` cells around its point in one symbolic loop whose every iteration either
processes one inducing point or moves on to the next cell. Kernel values under the cut are never
formed, so no denormal reaches any product.

Two kernels share the loop: ``kernel_sum`` (lane -> sum_j c_j k(x, nu_j)) and ``kernel_scatter``
(``out[j] += g_lane k(x_lane, nu_j)``, the adjoint, used for the SGD gradient).

:class:`LatticeGrid` holds nodes that sit on a regular lattice (those of
:class:`~hilbertmap.IncrementalHilbertMap`) for the same two kernels without any search: a lane's
lattice cell gives its neighbouring nodes directly, and the RBF factorises over the axes.
"""
from __future__ import annotations

import math

import numpy as np

import drjit as dr

from ._exact import ExactSum
from .inducing import sorted_unique

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
                out.add(g * kv, j, m)
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
        """``out[j] += g * k(x, nu_j)`` for every lane (grid order), through integer atomics whose
        sums do not depend on the threads' order (`_exact`); ``out`` is written and returned."""
        acc = ExactSum(self.mod, self.n)
        self._loop(x, y, z, g=g, out=acc)
        new = out + self.Float(acc.total())
        dr.eval(new)
        dr.scatter(out, new, dr.arange(self.UInt32, self.n))
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


BRICK_SHIFT = 3  # LatticeGrid tiles of 8 x 8 columns, and bricks of 8^3 cells for near()
BRICK = 1 << BRICK_SHIFT


class LatticeGrid:
    """Nodes on a regular lattice (node ``j`` at ``(k_j + 1/2) h`` for integer ``k_j``), held for
    the same two kernels as :class:`KernelGrid` without any search.

    A lane at ``x`` lies in lattice cell ``i = floor(x / h)``; the nodes whose kernel reaches it
    are among ``i + o`` for the fixed offsets ``o`` with ``sum_a max(|o_a| - 1/2, 0)^2 h^2 < r_cut^2``
    (251 offsets for ``r_cut = 3.03 h``: ``lengthscale = h``, ``kernel_cut = 1e-2``); of these a
    lane visits the 163 that can reach its octant of the cell (mirrored per axis), as columns along
    z (one symbolic loop per column extent, the column's cells unrolled). The RBF
    factorises over the axes, ``exp(-gamma |d|^2) = prod_a exp(-gamma d_a^2)`` with
    ``d_a = (f_a - o_a - 1/2) h`` and ``f = x / h - i``: a lane forms ``2R + 1`` exponentials in z,
    one per column, and one product and one masked gather per offset.

    Storage: the nodes of each (x, y) lattice column, densely from the lowest to the highest z
    (0 in the gaps): the "column store", ``pos[j]`` the entry of node ``j``. A column's header
    (its first entry, lowest z and length, 64 bits) sits in a tile of 8 x 8 columns; a dense table
    over the nodes' box gives each tile holding nodes its 64 headers (0: none, tile 0 is all
    zeros). A lane reads one table entry and one header per column, then one masked gather per
    offset. Memory: ``4 bytes x (tiles in the box + column store) + 512 bytes x tiles used``;
    the harbour's 200 k nodes take 1.3 MB of store. The adjoint adds into a zeroed copy of the
    store and reads each node's entry back.

    Node order is the caller's (``order`` is the identity, kept for :class:`KernelGrid`'s interface).
    The kernel is cut where ``|d|^2 >= r_cut^2``, the same set as :class:`KernelGrid`.
    """

    def __init__(self, lattice_index: np.ndarray, h: float, lengthscale: float, kernel_cut: float,
                 variant: str = "llvm"):
        mod = _variant(variant)
        self.mod = mod
        self.Float, self.UInt32, self.Int32 = mod.Float, mod.UInt32, mod.Int32
        idx = np.asarray(lattice_index, dtype=np.int64).reshape(-1, 3)
        self.n = len(idx)
        self.h = float(h)
        self.lengthscale = float(lengthscale)
        self.kernel_cut = float(kernel_cut)
        self.r_cut = cut_radius(lengthscale, kernel_cut)
        self._gamma = 1.0 / (2.0 * self.lengthscale ** 2)
        self.order = np.arange(self.n)
        self.inv_order = self.order
        rr = self.r_cut / self.h
        self.R = int(math.floor(rr + 0.5))
        while self.R - 0.5 >= rr:
            self.R -= 1
        offs = np.stack(np.meshgrid(*[np.arange(-self.R, self.R + 1)] * 3, indexing="ij"), -1).reshape(-1, 3)
        reach = np.sum(np.maximum(np.abs(offs) - 0.5, 0.0) ** 2, axis=1) * self.h ** 2
        self.offsets = offs[reach < self.r_cut ** 2]
        # The offsets that can reach a lane in the lower octant of its cell (f < 1/2 on every
        # axis): |o_a + 1/2 - f_a| >= o_a for o_a >= 0 and >= |o_a| - 1/2 below. A lane in another
        # octant visits their mirror image (o_a -> -o_a on the axes where f_a >= 1/2): 163
        # offsets instead of 251 for r_cut = 3.03 h.
        low = np.where(offs >= 0, offs, np.abs(offs) - 0.5).astype(np.float64)
        canon = offs[np.sum(low ** 2, axis=1) * self.h ** 2 < self.r_cut ** 2]
        self.n_visits = len(canon)
        cols = {}
        for ox, oy, oz in canon.tolist():
            lo, hi = cols.get((ox, oy), (oz, oz))
            cols[(ox, oy)] = (min(lo, oz), max(hi, oz))
        self._groups = {}  # (z from, z to) -> columns (ox, oy)
        for (ox, oy), zr in sorted(cols.items()):
            self._groups.setdefault(zr, []).append((ox, oy))
        self._build(idx)

    def _build(self, idx):
        self.base = idx.min(axis=0) if self.n else np.zeros(3, dtype=np.int64)
        rel = idx - self.base
        D = self.dims = rel.max(axis=0) + 1 if self.n else np.ones(3, dtype=np.int64)
        if D[2] >= 1 << 16:
            raise ValueError(f"HilbertMap: the nodes span {D[2]} lattice cells in z; at most 65535 are supported")
        # columns: the nodes of one (x, y) cell, stored densely from their lowest to highest z
        col = rel[:, 0] * D[1] + rel[:, 1]
        order = np.argsort(col * D[2] + rel[:, 2])
        cs = col[order]
        first = np.r_[0, np.nonzero(cs[1:] != cs[:-1])[0] + 1] if self.n else np.zeros(0, dtype=np.int64)
        last = np.r_[first[1:], len(cs)] - 1 if self.n else first
        ucol = cs[first]
        zmin = rel[order[first], 2]
        length = rel[order[last], 2] - zmin + 1
        start = np.r_[0, np.cumsum(length)[:-1]].astype(np.int64)
        inv = np.repeat(np.arange(len(ucol)), last - first + 1)
        pos = np.empty(self.n, dtype=np.int64)
        pos[order] = start[inv] + rel[order, 2] - zmin[inv]
        self.pool_size = int(length.sum()) if self.n else 1
        # column headers (start << 32 | zmin << 16 | length) in tiles of 8 x 8 columns; a dense
        # table over the box gives each tile holding nodes its 64 headers (0: none, tile 0 is empty)
        ux, uy = ucol // D[1], ucol % D[1]
        self.tdims = (D[:2] + BRICK - 1) >> BRICK_SHIFT
        tkey = (ux >> BRICK_SHIFT) * self.tdims[1] + (uy >> BRICK_SHIFT)
        utile = sorted_unique(tkey)
        tinv = np.searchsorted(utile, tkey)
        tiles = np.zeros(int(np.prod(self.tdims)), dtype=np.uint32)
        tiles[utile] = (np.arange(len(utile), dtype=np.uint32) + 1) * BRICK * BRICK
        headers = np.zeros((len(utile) + 1) * BRICK * BRICK, dtype=np.uint64)
        headers[(tinv + 1) * BRICK * BRICK + (ux & (BRICK - 1)) * BRICK + (uy & (BRICK - 1))] = (
            (start.astype(np.uint64) << np.uint64(32)) | (zmin.astype(np.uint64) << np.uint64(16))
            | length.astype(np.uint64))
        self.tiles = upload(self.UInt32, tiles, np.uint32)
        self.headers = upload(self.mod.UInt64, headers, np.uint64)
        self.pos = upload(self.UInt32, pos, np.uint32)
        # occupancy of bricks of 8^3 cells, for near()
        self.bdims = (D + BRICK - 1) >> BRICK_SHIFT
        bk = rel >> BRICK_SHIFT
        self._top_np = np.zeros(int(np.prod(self.bdims)), dtype=bool)
        self._top_np[(bk[:, 0] * self.bdims[1] + bk[:, 1]) * self.bdims[2] + bk[:, 2]] = True

    def upload(self, values) -> "Float":
        """A float32 Dr.Jit array of this grid's variant (see `upload`)."""
        return upload(self.Float, values, np.float32)

    def to_lanes(self, pts: np.ndarray):
        p = np.asarray(pts, dtype=np.float32)
        return self.upload(p[:, 0]), self.upload(p[:, 1]), self.upload(p[:, 2])

    def sort_keys(self, pts: np.ndarray) -> np.ndarray:
        """An int64 key per point, equal for points in the same block of ``4^3`` lattice cells
        and ordered x-major: sorting lanes by it gives neighbouring lanes the same nodes."""
        i = np.floor(np.asarray(pts, dtype=np.float64).reshape(-1, 3) / (4.0 * self.h)).astype(np.int64)
        i -= i.min(axis=0) if len(i) else 0
        return (i[:, 0] << 42) | (i[:, 1] << 21) | i[:, 2]

    def near(self, pts: np.ndarray) -> np.ndarray:
        """Whether a brick holding nodes meets the box of offsets around each point: a superset
        of the points that some node's kernel reaches (the others need no kernel work)."""
        pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
        if self.n == 0 or len(pts) == 0:
            return np.zeros(len(pts), dtype=bool)
        i = np.floor(pts / self.h) - self.base
        i = np.clip(i, -self.R - 1, self.dims + self.R).astype(np.int64)
        lo_b = (i - self.R) >> BRICK_SHIFT
        K = (2 * self.R + 7) // BRICK + 1
        out = np.zeros(len(pts), dtype=bool)
        D = self.bdims
        steps = range(K)
        for kx in steps:
            for ky in steps:
                for kz in steps:
                    cx, cy, cz = lo_b[:, 0] + kx, lo_b[:, 1] + ky, lo_b[:, 2] + kz
                    ok = (cx >= 0) & (cy >= 0) & (cz >= 0) & (cx < D[0]) & (cy < D[1]) & (cz < D[2])
                    k = np.where(ok, (cx * D[1] + cy) * D[2] + cz, 0)
                    out |= ok & self._top_np[k]
        return out

    def _columns(self, x, y, z, coef_pool=None, g=None, out=None):
        Float, UInt32, Int32 = self.Float, self.UInt32, self.Int32
        R, h = self.R, self.h
        inv_h = dr.opaque(Float, 1.0 / h)
        hh = dr.opaque(Float, h)
        gamma = dr.opaque(Float, self._gamma)
        rc2 = dr.opaque(Float, self.r_cut ** 2)
        D = [dr.opaque(Int32, int(v)) for v in self.dims]
        ty = dr.opaque(Int32, int(self.tdims[1]))
        frac, cell = [], []
        for a, c in enumerate((x, y, z)):
            u = c * inv_h - dr.opaque(Float, float(self.base[a]))
            # the box changes with every rebuild: an opaque bound, or each grid compiles its own kernels
            fl = dr.clip(dr.floor(u), -R - 1.0, dr.opaque(Float, float(self.dims[a] + R)))
            frac.append(u - fl)
            cell.append(Int32(fl))
        # the octant of the lane in its cell: offsets are mirrored where f >= 1/2
        sgn = [dr.select(f < 0.5, 1, -1) for f in frac]
        sgnf = [Float(v) for v in sgn]
        zs = {}
        for o in range(-R, R + 1):
            d2 = dr.square((frac[2] - (sgnf[2] * o + 0.5)) * hh)
            zs[o] = (d2, dr.exp(-gamma * d2), cell[2] + sgn[2] * o)
        acc = dr.zeros(Float, dr.width(x))
        mask16 = dr.opaque(self.mod.UInt64, 0xFFFF)
        for (z0, z1), cols in self._groups.items():
            cox = upload(Int32, [c[0] for c in cols], np.int32)
            coy = upload(Int32, [c[1] for c in cols], np.int32)
            n_cols = len(cols)

            def body(i, acc, z0=z0, z1=z1, cox=cox, coy=coy):
                ox = dr.gather(Int32, cox, i) * sgn[0]
                oy = dr.gather(Int32, coy, i) * sgn[1]
                dxy2 = dr.square((frac[0] - Float(ox) - 0.5) * hh) + dr.square((frac[1] - Float(oy) - 0.5) * hh)
                exy = dr.exp(-gamma * dxy2)
                cx, cy = cell[0] + ox, cell[1] + oy
                live = (cx >= 0) & (cx < D[0]) & (cy >= 0) & (cy < D[1]) & (dxy2 < rc2)
                tile = dr.gather(UInt32, self.tiles, UInt32((cx >> BRICK_SHIFT) * ty + (cy >> BRICK_SHIFT)), live)
                hdr = dr.gather(self.mod.UInt64, self.headers,
                                tile + UInt32((cx & (BRICK - 1)) * BRICK + (cy & (BRICK - 1))), live)
                start = UInt32(hdr >> 32)
                zmin = Int32(UInt32((hdr >> 16) & mask16))
                length = UInt32(hdr & mask16)
                for o in range(z0, z1 + 1):
                    dz2, ez, cz = zs[o]
                    zoff = UInt32(cz - zmin)
                    m = (zoff < length) & (dxy2 + dz2 < rc2)
                    k = start + zoff
                    kv = exy * ez
                    if out is None:
                        acc = dr.fma(kv, dr.gather(Float, coef_pool, k, m), acc)
                    else:  # into the column store; kernel_scatter reads the nodes' entries back
                        out.add(g * kv, k, m)
                return i + 1, acc

            i = dr.zeros(UInt32, dr.width(x))
            i, acc = dr.while_loop((i, acc), lambda i, acc, n_cols=n_cols: i < n_cols, body,
                                   label=f"hilbertmap_lattice_{z0}_{z1}")
        return acc

    def pooled(self, coef):
        """The node coefficients (a Dr.Jit Float, node order) laid out as the column store (0 in
        the gaps of a column): what :meth:`kernel_sum` reads."""
        cp = dr.zeros(self.Float, self.pool_size)
        dr.scatter(cp, coef, self.pos)
        return cp

    def update_pooled(self, pool, coef, mask):
        """Write the coefficients of the nodes in ``mask`` into ``pool``."""
        dr.scatter(pool, coef, self.pos, mask)

    def kernel_sum(self, x, y, z, coef, pooled=False):
        """Lane-wise ``sum_j coef[j] k(x, nu_j)`` (``coef`` a Dr.Jit Float in node order, or
        already laid out by :meth:`pooled` when ``pooled``)."""
        return self._columns(x, y, z, coef_pool=coef if pooled else self.pooled(coef))

    def kernel_scatter(self, x, y, z, g, out):
        """``out + (sum over lanes of g k(x, nu_j))_j`` (a new array; ``out`` is not written):
        atomic additions into a zeroed copy of the column store (no node index to look up per
        neighbour), then each node's entry. The additions are integer (`_exact`): the same sums
        whatever the threads' order."""
        buf = ExactSum(self.mod, self.pool_size)
        self._columns(x, y, z, g=g, out=buf)
        return out + dr.gather(self.Float, self.Float(buf.total()), self.pos)

    def brick_keys(self, pts: np.ndarray) -> np.ndarray:
        """The linear index of each point's brick, clamped into the box (uint16 when the box has
        at most 65536 bricks, so that a stable argsort is a radix sort)."""
        p = np.asarray(pts, dtype=np.float32).reshape(-1, 3)
        D = self.bdims
        key = np.zeros(len(p), dtype=np.int64)
        for a in range(3):
            b = np.floor(p[:, a] * np.float32(1.0 / (self.h * BRICK)) - np.float32(self.base[a] / BRICK))
            key = key * int(D[a]) + np.clip(b, 0, D[a] - 1).astype(np.int64)
        return key.astype(np.uint16 if np.prod(D) <= 1 << 16 else np.uint32)

    def kernel_sum_at(self, pts: np.ndarray, coef, pooled=False) -> np.ndarray:
        """``sum_j coef[j] k(x, nu_j)`` at (N, 3) world points, float64 in the points' order.

        The lanes take the points in brick order (a radix sort of :meth:`brick_keys`: neighbouring
        lanes read the same blocks); the permutation is a gather and a scatter inside the kernel."""
        pts = np.asarray(pts, dtype=np.float32).reshape(-1, 3)
        if len(pts) == 0:
            return np.zeros(0)
        order = upload(self.UInt32, np.argsort(self.brick_keys(pts), kind="stable"), np.uint32)
        X, Y, Z = self.to_lanes(pts)
        x, y, z = (dr.gather(self.Float, c, order) for c in (X, Y, Z))
        f = self.kernel_sum(x, y, z, coef, pooled)
        res = dr.zeros(self.Float, len(pts))
        dr.scatter(res, f, order)
        return res.numpy().astype(np.float64)
