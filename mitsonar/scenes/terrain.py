"""Procedural seabed terrain: a seeded height field (slope, sand ripples, random roughness,
scattered rocks) written as a binary PLY mesh that Mitsuba's ``ply`` shape loads.

    from mitsonar.scenes.terrain import Terrain
    t = Terrain(size=(40, 40), resolution=0.05, depth=-10, slope=(0.05, 0), ripple_wavelength=0.6,
                ripple_height=0.05, roughness=0.02, rocks=30, seed=1)
    t.write_ply("seabed.ply")

or ``python -m mitsonar.scenes.terrain seabed.ply --size 40 40 --resolution 0.05 ...`` (``--help``).

The heights on a regular grid of spacing ``resolution`` are

    z(x, y) = depth + slope . (x, y) + ripple_height sin(2 pi k . (x, y) / ripple_wavelength + phase)
              + roughness field + rocks

with ``k`` the unit vector at ``ripple_direction`` (deg from +x; the crests run across it), the
phase uniform, the roughness field gaussian (gaussian spectrum, correlation length
``correlation_length``) scaled so that its sample rms over the grid is exactly ``roughness``, and
each rock a half-ellipsoid cap of radius uniform in ``rock_radius`` (height 0.6 times it) at a
uniform position. All random draws come from ``numpy.random.default_rng(seed)``: the same
arguments give the same mesh, byte for byte.

Resolution against range bins: a side-scan ping of 1000 bins over 50 m has 5 cm bins; a grid cell
of ``resolution`` spans up to ``resolution * sqrt(2)`` in slant range at grazing incidence, so for
facets not to show as steps in the image take ``resolution`` no coarser than the bin width
(``resolution <= range / n_bins``: 0.05 m for 50 m in 1000 bins) and at most a quarter of the
ripple wavelength, so that ripples are drawn with at least four cells per wavelength.
Each cell is two triangles; a square terrain of side L has ``2 (L / resolution)^2`` of them
(40 m at 0.05 m: 1.28 M triangles, 24 MB of PLY).

The mesh is the height field's surface (normals up, counter-clockwise seen from above); with
``closed=True`` it also gets four vertical skirts down to ``bottom`` and a flat bottom face, so it
is watertight (every edge shared by exactly two triangles, consistently oriented, normals out).
"""
from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from mitsonar._checks import in_range, is_number, is_whole, require

#: Most grid vertices a terrain may have: making and writing the mesh peaks at about 270 bytes
#: each (heights and their parts, the roughness field's FFT, vertex and face arrays; measured on
#: a 1 M-vertex closed terrain), so about 2.2 GB at most. 8 M vertices: 0.02 m cells on 56 x 56 m.
MAX_VERTICES = 8_000_000

WHERE = "terrain"


def _check_positive(name, value):
    require(is_number(value) and value > 0, WHERE, name, value, "a number > 0")


def height_field_faces(ny, nx):
    """The triangles (int64 (2 (ny-1)(nx-1), 3)) of a height field whose ``ny * nx`` vertices are
    stored row by row (x fastest, rows along +y): two per cell, counter-clockwise seen from above
    (normals up); cell ``(j, i)``'s two are rows ``k`` and ``k + (ny-1)(nx-1)``, ``k = j (nx-1) + i``."""
    idx = np.arange(nx * ny, dtype=np.int64).reshape(ny, nx)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()        # (i, j), (i+1, j)
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()          # (i, j+1), (i+1, j+1)
    return np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])


class Terrain:
    """A seeded seabed height field on ``size = (Lx, Ly)`` metres from ``centre - size / 2``
    (see the module docstring for the model; every length in metres, angles in degrees). The grid
    covers each side rounded down to a whole number of cells (16 m at 0.12 m: 15.96 m)."""

    def __init__(self, size=(40.0, 40.0), resolution=0.05, *, centre=(0.0, 0.0), depth=0.0,
                 slope=(0.0, 0.0), ripple_wavelength=0.6, ripple_height=0.0, ripple_direction=0.0,
                 roughness=0.0, correlation_length=1.0, rocks=0, rock_radius=(0.2, 0.6), seed=0,
                 closed=False, bottom=None):
        size = tuple(size) if np.ndim(size) else (size, size)
        require(len(size) == 2, WHERE, "size", size, "two numbers > 0, Lx Ly in m")
        _check_positive("size", size[0])
        _check_positive("size", size[1])
        _check_positive("resolution", resolution)
        n = [int(math.floor(s / resolution + 1e-9)) + 1 for s in size]
        finest = math.sqrt(size[0] * size[1] / MAX_VERTICES)
        require(n[0] >= 2 and n[1] >= 2, WHERE, "resolution", resolution,
                f"a grid spacing > 0 and <= the smaller side, {min(size):g} m")
        require(n[0] * n[1] <= MAX_VERTICES, WHERE, "resolution", resolution,
                f"a grid spacing >= about {finest:.3g} m for a {size[0]:g} x {size[1]:g} m terrain: "
                f"at most {MAX_VERTICES} vertices")
        for name, v in (("depth", depth), ("ripple_direction", ripple_direction)):
            require(is_number(v), WHERE, name, v, "a finite number")
        for name, v in (("ripple_height", ripple_height), ("roughness", roughness)):
            require(is_number(v) and v >= 0, WHERE, name, v, "a number >= 0")
        for name, v in (("ripple_wavelength", ripple_wavelength), ("correlation_length", correlation_length)):
            _check_positive(name, v)
        require(len(tuple(slope)) == 2 and all(is_number(v) for v in slope), WHERE, "slope", slope,
                "two gradients dz/dx dz/dy")
        require(len(tuple(centre)) == 2 and all(is_number(v) for v in centre), WHERE, "centre", centre,
                "two numbers, x y in m")
        require(is_whole(rocks) and rocks >= 0, WHERE, "rocks", rocks, "a count >= 0")
        require(len(tuple(rock_radius)) == 2 and all(is_number(v) for v in rock_radius)
                and 0 < rock_radius[0] <= rock_radius[1], WHERE, "rock_radius", rock_radius,
                "two radii 0 < r_min <= r_max in m")
        require(is_whole(seed) and seed >= 0, WHERE, "seed", seed, "a whole number >= 0")
        require(isinstance(closed, bool), WHERE, "closed", closed, "True or False")
        self.size = (float(size[0]), float(size[1]))
        self.resolution = float(resolution)
        self.shape = (n[1], n[0])  # rows along y, columns along x
        self.centre = (float(centre[0]), float(centre[1]))
        self.depth, self.slope = float(depth), (float(slope[0]), float(slope[1]))
        self.ripple_wavelength, self.ripple_height = float(ripple_wavelength), float(ripple_height)
        self.ripple_direction = float(ripple_direction)
        self.roughness, self.correlation_length = float(roughness), float(correlation_length)
        self.rocks, self.rock_radius = int(rocks), (float(rock_radius[0]), float(rock_radius[1]))
        self.seed, self.closed = int(seed), closed
        self.x = self.centre[0] - self.size[0] / 2 + self.resolution * np.arange(n[0])
        self.y = self.centre[1] - self.size[1] / 2 + self.resolution * np.arange(n[1])
        self.components = self._heights()
        self.z = sum(self.components.values())
        lowest = float(self.z.min())
        self.bottom = lowest - 1.0 if bottom is None else bottom
        require(in_range(self.bottom, -math.inf, lowest) and self.bottom < lowest, WHERE, "bottom",
                bottom, f"a height below the lowest point of the terrain, {lowest:g} m")

    # ------------------------------------------------------------------ heights
    def _heights(self):
        rng = np.random.default_rng(self.seed)
        X, Y = np.meshgrid(self.x, self.y)
        out = {"plane": self.depth + self.slope[0] * (X - self.centre[0]) + self.slope[1] * (Y - self.centre[1])}
        phase = rng.uniform(0, 2 * math.pi)
        a = math.radians(self.ripple_direction)
        along = (X * math.cos(a) + Y * math.sin(a)) / self.ripple_wavelength
        out["ripples"] = self.ripple_height * np.sin(2 * math.pi * along + phase)
        noise = rng.standard_normal(self.shape)
        rough = np.zeros(self.shape)
        if self.roughness > 0:
            ky = np.fft.fftfreq(self.shape[0], self.resolution)[:, None]
            kx = np.fft.rfftfreq(self.shape[1], self.resolution)[None, :]
            filt = np.exp(-(math.pi * self.correlation_length) ** 2 * (kx ** 2 + ky ** 2))
            rough = np.fft.irfft2(np.fft.rfft2(noise) * filt, s=self.shape)
            rough -= rough.mean()
            rms = float(np.sqrt(np.mean(rough ** 2)))
            rough *= self.roughness / rms if rms > 0 else 0.0
        out["roughness"] = rough
        rocks = np.zeros(self.shape)
        centres = np.stack([rng.uniform(self.x[0], self.x[-1], self.rocks),
                            rng.uniform(self.y[0], self.y[-1], self.rocks)], 1)
        radii = rng.uniform(*self.rock_radius, self.rocks)
        for (cx, cy), r in zip(centres, radii):
            i0, i1 = np.searchsorted(self.x, [cx - r, cx + r])
            j0, j1 = np.searchsorted(self.y, [cy - r, cy + r])
            d2 = ((X[j0:j1, i0:i1] - cx) ** 2 + (Y[j0:j1, i0:i1] - cy) ** 2) / r ** 2
            cap = 0.6 * r * np.sqrt(np.clip(1 - d2, 0, None))
            rocks[j0:j1, i0:i1] = np.maximum(rocks[j0:j1, i0:i1], cap)
        self.rock_centres, self.rock_radii = centres, radii
        out["rocks"] = rocks
        return out

    def height(self, x, y):
        """Height at (x, y) inside the terrain (clamped to it): bilinear interpolation of the grid,
        exact at the vertices; inside a cell the mesh's two triangles differ from it by at most a
        quarter of the cell's twist ``|z00 + z11 - z10 - z01|``. For placing objects on the seabed."""
        fx = np.clip((np.asarray(x, float) - self.x[0]) / self.resolution, 0, len(self.x) - 1 - 1e-9)
        fy = np.clip((np.asarray(y, float) - self.y[0]) / self.resolution, 0, len(self.y) - 1 - 1e-9)
        i, j = fx.astype(int), fy.astype(int)
        u, v = fx - i, fy - j
        z = self.z
        return ((1 - u) * (1 - v) * z[j, i] + u * (1 - v) * z[j, i + 1]
                + (1 - u) * v * z[j + 1, i] + u * v * z[j + 1, i + 1])

    # ------------------------------------------------------------------ mesh
    def mesh(self):
        """``(vertices (V, 3) float64, faces (F, 3) int64)``: the surface, and with ``closed`` the
        skirts and the bottom."""
        ny, nx = self.shape
        X, Y = np.meshgrid(self.x, self.y)
        verts = np.stack([X.ravel(), Y.ravel(), self.z.ravel()], 1)
        idx = np.arange(nx * ny).reshape(ny, nx)
        faces = [height_field_faces(ny, nx)]
        if self.closed:
            # The boundary loop, counter-clockwise seen from above, and its copy at the bottom.
            ring = np.concatenate([idx[0, :-1], idx[:-1, -1], idx[-1, :0:-1], idx[:0:-1, 0]])
            base = len(verts)
            low = verts[ring].copy()
            low[:, 2] = self.bottom
            middle = [[self.centre[0], self.centre[1], self.bottom]]
            verts = np.concatenate([verts, low, middle])
            m = len(ring)
            k = np.arange(m)
            top0, top1 = ring, ring[(k + 1) % m]
            bot0, bot1 = base + k, base + (k + 1) % m
            # Skirt quad top0 -> top1 -> bot1 -> bot0, normal out of the solid.
            faces += [np.stack([top0, bot1, top1], 1), np.stack([top0, bot0, bot1], 1)]
            # Bottom: a fan from its middle over the bottom loop (a rectangle's outline), normal down.
            faces.append(np.stack([np.full(m, base + m), bot1, bot0], 1))
        return verts, np.concatenate(faces).astype(np.int64)

    def write_ply(self, path):
        """Write the mesh as a binary little-endian PLY (float x y z, uchar/int face lists;
        `mitsonar.geometry.ply`) under a temporary name, renamed onto ``path`` when complete. Returns
        ``(n_vertices, n_faces)``."""
        from mitsonar.geometry.ply import write_ply

        verts, faces = self.mesh()
        rows = np.empty(len(verts), [("x", "<f4"), ("y", "<f4"), ("z", "<f4")])
        rows["x"], rows["y"], rows["z"] = verts.T
        write_ply(path, rows, faces, comment=f"mitsonar terrain seed {self.seed}")
        return len(verts), len(faces)


def read_ply(path):
    """Read back a PLY written by :meth:`Terrain.write_ply`: ``(vertices, faces)``."""
    from mitsonar.geometry.ply import read_ply as read

    rows, faces = read(path)
    return np.stack([rows["x"], rows["y"], rows["z"]], 1).astype(np.float64), faces


def main(argv=None):
    p = argparse.ArgumentParser(prog="python -m mitsonar.scenes.terrain", description=__doc__.split("\n\n")[0])
    p.add_argument("output", help="PLY file to write")
    p.add_argument("--size", nargs=2, type=float, default=(40.0, 40.0), metavar=("LX", "LY"), help="m (40 40)")
    p.add_argument("--resolution", type=float, default=0.05, help="grid spacing, m (0.05)")
    p.add_argument("--centre", nargs=2, type=float, default=(0.0, 0.0), metavar=("X", "Y"))
    p.add_argument("--depth", type=float, default=0.0, help="mean height at the centre, m (0)")
    p.add_argument("--slope", nargs=2, type=float, default=(0.0, 0.0), metavar=("DZDX", "DZDY"))
    p.add_argument("--ripple-wavelength", type=float, default=0.6, help="m (0.6)")
    p.add_argument("--ripple-height", type=float, default=0.0, help="amplitude, m (0)")
    p.add_argument("--ripple-direction", type=float, default=0.0, help="deg from +x (0)")
    p.add_argument("--roughness", type=float, default=0.0, help="rms, m (0)")
    p.add_argument("--correlation-length", type=float, default=1.0, help="m (1)")
    p.add_argument("--rocks", type=int, default=0, help="count (0)")
    p.add_argument("--rock-radius", nargs=2, type=float, default=(0.2, 0.6), metavar=("MIN", "MAX"))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--closed", action="store_true", help="add skirts and a bottom: a watertight solid")
    a = p.parse_args(argv)
    try:
        t = Terrain(a.size, a.resolution, centre=a.centre, depth=a.depth, slope=a.slope,
                    ripple_wavelength=a.ripple_wavelength, ripple_height=a.ripple_height,
                    ripple_direction=a.ripple_direction, roughness=a.roughness,
                    correlation_length=a.correlation_length, rocks=a.rocks, rock_radius=a.rock_radius,
                    seed=a.seed, closed=a.closed)
        nv, nf = t.write_ply(a.output)
    except (ValueError, OSError) as exc:
        print(f"mitsonar.scenes.terrain: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {a.output}: {nv} vertices, {nf} triangles of {t.resolution:g} m")
    return 0


if __name__ == "__main__":
    sys.exit(main())
