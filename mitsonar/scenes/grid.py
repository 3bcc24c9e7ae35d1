"""A seabed from a bathymetric grid: any raster GDAL reads (GeoTIFF, BAG, NetCDF/GEBCO, ASCII
grid), through rasterio, turned into a mesh scene in the grid's projected CRS.

    from mitsonar.scenes import seabed_from_grid
    site = seabed_from_grid("site.tif", "site.xml")       # site.xml + site_seabed.ply
    site.frame.crs, site.frame.e0, site.frame.n0           # 'EPSG:32631', 431000.0, 5761000.0

or ``mitsonar scene from-grid site.tif -o site.xml`` (docs/tutorials/your_world.rst).

Frame. The scene's world x, y are offsets in the grid's projected CRS from an origin
(``x = E - E0``, ``y = N - N0``, the `mitsonar.geometry.geodesy.GeoFrame` of ``--origin`` and
``--crs``); the origin is the grid's centre rounded to the metre unless ``origin`` says otherwise,
and the scene records it (`mitsonar.geometry.geodesy.scene_frame`), so ``survey`` and ``bathymetry`` over the
scene write their products (LAS, GeoTIFF, BAG, XTF, kmall) at the grid's own coordinates without
``--origin``. z = 0 is the sea surface: a vertex's z is the grid's height (``positive="up"``) or
minus its depth (``"down"``) plus ``vertical_offset`` (the height of the grid's vertical datum
above the sea surface). The sense is read from the file where it says it (a BAG: elevation; a band
or variable named depth or elevation/height; a ``positive`` tag, as mitsonar's own GeoTIFFs and
CF NetCDF carry), else ``positive`` must be given.

CRS. The grid's CRS (EPSG, WKT or a compound CRS: its horizontal part) must be projected in metres
with an EPSG code; a geographic grid (GEBCO, most NetCDF) or one in other units is reprojected to
``crs`` or the UTM zone of its centre. A grid without a CRS is refused.

Cells. A vertex sits at the centre of each cell of GDAL's area convention: a pixel-is-point
GeoTIFF's values are at its points (GDAL shifts its transform by half a cell, so the centres are
the points), a pixel-is-area one's at its cells' centres. ``bounds`` (xmin ymin xmax ymax, in the
grid's CRS) keep the cells whose centres lie inside; without ``resolution`` and reprojection the
values are the file's, unchanged; otherwise the grid is resampled (``resampling``, bilinear by
default) onto cells of ``resolution`` m aligned on multiples of it. Nodata cells inside the bounds
are refused (crop them away with ``bounds``, or fill the grid first).

Large grids (levels of detail). A mesh of more than ``max_vertices`` vertices (default the
terrain generator's cap, `mitsonar.scenes.terrain.MAX_VERTICES`, 8 M) is not written at the
file's cell: the cell is doubled (level 1, 2, ...) until it fits, the grid resampled with
``"average"`` (each coarse vertex the mean of the fine cells under it), and the level is said in
the result (``lod``) and the output line. An explicit ``resolution`` that would exceed the cap is
refused. A 4000 x 4000 grid becomes a 2000 x 2000 mesh (4 M vertices, 8 M triangles, one shape
``seabed``; measured in benchmarks/grid_scene.py).

Sediments. ``sediment`` (a raster of integer classes, any CRS GDAL can reproject) and
``sediment_map`` (a CSV ``class,material``, materials as `mitsonar.scenes.worldxml` names them)
give each cell of the seabed the material of the class at its centre (nearest cell): one PLY and
one shape per class, ids ``seabed_<material>`` (``seabed_mud`` for ``seabed_mud`` or ``mud``;
`mitsonar.products.sidescan.seabed_of_scene` takes them together as the seabed); without them the whole seabed is one shape
``seabed`` (what the side-scan products look for) of ``material``.
"""
from __future__ import annotations

import csv
import math
import os
import warnings
from dataclasses import dataclass, field

import numpy as np

from mitsonar._checks import first_line
from mitsonar.scenes.terrain import MAX_VERTICES, height_field_faces

RESAMPLING = ("bilinear", "nearest", "cubic", "average")
POSITIVE = ("up", "down")


class GridError(ValueError):
    """A grid, a flag or a mapping that cannot be used: one line naming the file or flag."""


def _rasterio(path):
    try:
        import pyproj  # noqa: F401
        import rasterio
    except ImportError:
        raise GridError(f"{path}: reading a grid needs rasterio and pyproj: pip install 'mitsonar[world]'") from None
    return rasterio


@dataclass
class Grid:
    """A height grid in a projected CRS: ``z`` (ny, nx) metres up from the sea surface, rows along
    +y (northing ascending), ``x``/``y`` the vertices' eastings and northings, ``crs`` "EPSG:NNNN",
    ``cell`` m, ``lod`` the level of detail (0: the file's cells; k: 2^k times coarser)."""

    z: np.ndarray
    x: np.ndarray
    y: np.ndarray
    crs: str
    cell: float
    source: str
    lod: int = 0
    positive: str = "up"
    notes: list = field(default_factory=list)

    def height(self, e, n):
        """Bilinear height at eastings/northings ``e``, ``n`` (NaN outside the grid)."""
        e, n = np.broadcast_arrays(np.asarray(e, float), np.asarray(n, float))
        fx = (e - self.x[0]) / (self.x[1] - self.x[0])
        fy = (n - self.y[0]) / (self.y[1] - self.y[0])
        ny, nx = self.z.shape
        inside = (fx >= 0) & (fx <= nx - 1) & (fy >= 0) & (fy <= ny - 1)
        fx, fy = np.clip(fx, 0, nx - 1 - 1e-9), np.clip(fy, 0, ny - 1 - 1e-9)
        i, j = fx.astype(int), fy.astype(int)
        u, v = fx - i, fy - j
        z = self.z
        out = ((1 - u) * (1 - v) * z[j, i] + u * (1 - v) * z[j, i + 1]
               + (1 - u) * v * z[j + 1, i] + u * v * z[j + 1, i + 1])
        return np.where(inside, out, np.nan)


def _horizontal(crs):
    """The horizontal part of a (possibly compound) pyproj CRS."""
    if crs.is_compound:
        for sub in crs.sub_crs_list:
            if sub.is_projected or sub.is_geographic:
                return sub
    return crs


def _epsg_name(crs):
    code = crs.to_epsg(min_confidence=70)
    return None if code is None else f"EPSG:{code}"


def _in_metres(crs) -> bool:
    return crs.is_projected and all((a.unit_name or "").lower() in ("metre", "meter", "m") for a in crs.axis_info[:2])


def _positive_of(src, path):
    """``"up"``/``"down"`` as the file says it, or None."""
    if src.driver == "BAG":
        return "up"
    said = set()
    tags = dict(src.tags())
    for b in range(1, src.count + 1):
        tags.update({f"band{b}:{k}": v for k, v in src.tags(b).items()})
    for k, v in tags.items():
        key, value = k.lower(), str(v).strip().lower()
        if key.endswith("positive") and value in POSITIVE:
            said.add(value)
        elif key.endswith("standard_name"):
            if value in ("depth", "sea_floor_depth_below_sea_surface", "sea_floor_depth_below_geoid"):
                said.add("down")
            elif value.startswith("height") or value.startswith("altitude") or "elevation" in value:
                said.add("up")
    desc = (src.descriptions[0] or "").strip().lower() if src.descriptions else ""
    if not said and desc:
        if "depth" in desc:
            said.add("down")
        elif "elevation" in desc or "height" in desc:
            said.add("up")
    if len(said) > 1:
        raise GridError(f"{path}: its metadata say both positive up and down; give --positive up|down")
    return said.pop() if said else None


def read_grid(path, *, bounds=None, resolution=None, resampling="bilinear", crs=None, positive=None,
              vertical_offset=0.0, max_vertices=MAX_VERTICES) -> Grid:
    """The `Grid` of a raster file (see the module docstring); every refusal is a `GridError`
    of one line naming the file or the flag, before anything is written."""
    rasterio = _rasterio(path)
    import pyproj
    from rasterio.warp import Resampling, reproject, transform_bounds

    from mitsonar.geometry.geodesy import GeoError, check_crs, utm_epsg

    path = os.fspath(path)
    if resampling not in RESAMPLING:
        raise GridError(f"--resampling {resampling}: not allowed ({', '.join(RESAMPLING)})")
    if positive is not None and positive not in POSITIVE:
        raise GridError(f"--positive {positive}: not allowed (up: heights, down: depths)")
    if not (isinstance(vertical_offset, (int, float)) and math.isfinite(vertical_offset)):
        raise GridError(f"--vertical-offset {vertical_offset}: not allowed (a finite number of metres)")
    if resolution is not None and not (math.isfinite(resolution) and resolution > 0):
        raise GridError(f"--resolution {resolution:g}: not allowed (a cell size > 0 in metres)")
    src = _open_raster(rasterio, path, str(path), "a raster GDAL reads: GeoTIFF, BAG, NetCDF, ASCII grid",
                       f"give the file its projected CRS first (gdal_edit.py -a_srs EPSG:NNNN {os.path.basename(path)})")
    with src:
        if src.transform.b != 0 or src.transform.d != 0:
            raise GridError(f"{path}: a rotated grid; warp it north-up first (gdalwarp)")
        src_crs = _horizontal(pyproj.CRS.from_user_input(src.crs.to_wkt()))
        sense = _positive_of(src, path)
        if sense is not None and positive is not None and sense != positive:
            raise GridError(f"--positive {positive}: {path} says its values are positive {sense}; drop --positive")
        sense = sense or positive
        if sense is None:
            raise GridError(f"{path}: its metadata do not say whether the values are heights or depths; "
                            "give --positive up (heights) or --positive down (depths)")
        # The CRS of the mesh.
        native = _in_metres(src_crs) and _epsg_name(src_crs)
        if crs is not None:
            try:
                dst_name, _ = check_crs(crs)
            except GeoError as exc:
                raise GridError(str(exc)) from None
        elif native:
            dst_name = native
        elif src_crs.is_projected and _in_metres(src_crs):
            raise GridError(f"{path}: its CRS ({src_crs.name}) has no EPSG code; give --crs EPSG:NNNN to reproject "
                            "it into one")
        else:
            left, bottom, right, top = src.bounds
            lon, lat = pyproj.Transformer.from_crs(src_crs, "EPSG:4326", always_xy=True).transform(
                (left + right) / 2, (bottom + top) / 2)
            dst_name = utm_epsg(lat, lon)
        dst_crs = pyproj.CRS.from_user_input(dst_name)
        same = native == dst_name
        # The area, in the grid's CRS, then in the mesh's.
        if bounds is not None:
            b = [float(v) for v in bounds]
            if len(b) != 4 or not all(math.isfinite(v) for v in b) or b[0] >= b[2] or b[1] >= b[3]:
                raise GridError(f"--bounds {' '.join(map(str, bounds))}: not allowed (XMIN YMIN XMAX YMAX in the "
                                "grid's CRS, XMIN < XMAX, YMIN < YMAX)")
            sb = src.bounds
            if b[2] <= sb.left or b[0] >= sb.right or b[3] <= sb.bottom or b[1] >= sb.top:
                raise GridError(f"--bounds {' '.join(f'{v:g}' for v in b)}: outside {path} "
                                f"({sb.left:g} {sb.bottom:g} {sb.right:g} {sb.top:g})")
            b = [max(b[0], sb.left), max(b[1], sb.bottom), min(b[2], sb.right), min(b[3], sb.top)]   # the overlap
        else:
            b = list(src.bounds)
        ta = src.transform
        if same:
            # Cells whose centres lie in the bounds, at the file's cells.
            c0 = max(0, math.ceil((b[0] - ta.c) / ta.a - 0.5))
            c1 = min(src.width - 1, math.floor((b[2] - ta.c) / ta.a - 0.5))
            r_top, r_bot = sorted(((b[3] - ta.f) / ta.e - 0.5, (b[1] - ta.f) / ta.e - 0.5))
            r0, r1 = max(0, math.ceil(r_top)), min(src.height - 1, math.floor(r_bot))
            if c1 - c0 < 1 or r1 - r0 < 1:
                raise GridError(f"--bounds: fewer than 2 x 2 cells of {path} inside them")
            native_cell = abs(ta.a)
            n_native = (c1 - c0 + 1) * (r1 - r0 + 1)
        else:
            b = list(transform_bounds(src.crs, dst_crs.to_wkt(), *b, densify_pts=21))
            native_cell = None
            n_native = None
        if same and resolution is None and abs(abs(ta.a) - abs(ta.e)) > 1e-9 * abs(ta.a):
            raise GridError(f"{path}: cells of {abs(ta.a):g} x {abs(ta.e):g} m are not square; give --resolution")
        lod = 0
        if same and resolution is None and n_native <= max_vertices:
            window = rasterio.windows.Window(c0, r0, c1 - c0 + 1, r1 - r0 + 1)
            values = src.read(1, window=window, masked=True).astype(np.float64)
            bad = np.ma.getmaskarray(values) | ~np.isfinite(values.filled(np.nan))
            values = values.filled(np.nan)
            cell = abs(ta.a)       # the window's cells' centres (by hand: affine's `*` is deprecated)
            xs = ta.c + (c0 + np.arange(values.shape[1]) + 0.5) * ta.a
            ys = ta.f + (r0 + np.arange(values.shape[0]) + 0.5) * ta.e
        else:
            if resolution is not None:
                cell = float(resolution)
            elif same:
                cell = native_cell
            else:   # the source's cell, measured in the new CRS (its size at the centre)
                from rasterio.warp import calculate_default_transform

                with warnings.catch_warnings():     # rasterio's own use of affine's deprecated `*`
                    warnings.simplefilter("ignore", PendingDeprecationWarning)
                    t, _, _ = calculate_default_transform(src.crs, dst_crs.to_wkt(), src.width, src.height,
                                                          *src.bounds)
                cell = float(abs(t.a) + abs(t.e)) / 2
            nx = int(math.floor((b[2] - b[0]) / cell + 1e-9))
            ny = int(math.floor((b[3] - b[1]) / cell + 1e-9))
            if resolution is not None and nx * ny > max_vertices:
                finest = math.sqrt((b[2] - b[0]) * (b[3] - b[1]) / max_vertices)
                raise GridError(f"--resolution {resolution:g}: {nx} x {ny} vertices, over the {max_vertices} a seabed "
                                f"mesh may have; give --resolution {finest:.3g} or more, or smaller --bounds")
            while nx * ny > max_vertices:
                lod += 1
                cell *= 2
                nx, ny = nx // 2, ny // 2
            if nx < 2 or ny < 2:
                raise GridError(f"{path}: fewer than 2 x 2 cells of {cell:g} m in the bounds; give a finer --resolution")
            # Cells aligned on multiples of the cell, inside the bounds.
            x0 = math.ceil(b[0] / cell - 1e-9) * cell
            y1 = math.floor(b[3] / cell + 1e-9) * cell
            nx = min(nx, int(math.floor((b[2] - x0) / cell + 1e-9)))
            ny = min(ny, int(math.floor((y1 - b[1]) / cell + 1e-9)))
            from rasterio.transform import Affine

            wt = Affine(cell, 0, x0, 0, -cell, y1)
            values = np.full((ny, nx), np.nan, np.float64)
            how = Resampling.average if lod and resampling == "bilinear" else getattr(Resampling, resampling)
            reproject(rasterio.band(src, 1), values, dst_transform=wt, dst_crs=dst_crs.to_wkt(), dst_nodata=np.nan,
                      resampling=how)
            xs = wt.c + (np.arange(nx) + 0.5) * cell
            ys = wt.f - (np.arange(ny) + 0.5) * cell
            if not same:      # the grid's outline, turned in the new CRS: its box's edges fall outside it
                values, xs, ys = _peel(values, xs, ys)
            bad = ~np.isfinite(values)
        if bad.any():
            rows, cols = np.nonzero(bad)
            raise GridError(f"{path}: {int(bad.sum())} nodata cells in the area (the first at easting "
                            f"{xs[cols[0]]:.2f}, northing {ys[rows[0]]:.2f}, {dst_name}); give --bounds that leave "
                            "them out, or fill them first (gdal_fillnodata.py)")
    z = (values if sense == "up" else -values) + float(vertical_offset)
    if ys[0] > ys[-1]:            # rows along +y
        z, ys = z[::-1], ys[::-1]
    return Grid(np.ascontiguousarray(z), np.asarray(xs, float), np.asarray(ys, float), dst_name, float(cell),
                path, lod, sense)


def _peel(values, xs, ys):
    """Drop the outer rows and columns that hold cells without data, the side with the most of
    them first, until the border is whole (a reprojected grid's box is larger than its outline)."""
    r0, r1, c0, c1 = 0, values.shape[0], 0, values.shape[1]
    while r1 - r0 > 1 and c1 - c0 > 1:
        nan = ~np.isfinite(values[r0:r1, c0:c1])
        sides = [nan[0].mean(), nan[-1].mean(), nan[:, 0].mean(), nan[:, -1].mean()]
        k = int(np.argmax(sides))
        if sides[k] == 0:
            break
        if k == 0:
            r0 += 1
        elif k == 1:
            r1 -= 1
        elif k == 2:
            c0 += 1
        else:
            c1 -= 1
    return values[r0:r1, c0:c1], xs[c0:c1], ys[r0:r1]


def read_sediment_map(path) -> dict:
    """``{class: material}`` from a CSV ``class,material`` (a header line optional; materials
    checked by `mitsonar.scenes.worldxml.check_material`)."""
    from mitsonar.scenes.worldxml import check_material

    if not os.path.isfile(path):
        raise GridError(f"--sediment-map {path}: no such file (a CSV: class,material per line)")
    out = {}
    with open(path, newline="") as f:
        for i, row in enumerate(csv.reader(f), start=1):
            if not row or not "".join(row).strip() or row[0].strip().startswith("#"):
                continue
            if len(row) < 2:
                raise GridError(f"{path}: line {i}: expected class,material")
            try:
                cls = int(row[0])
            except ValueError:
                if i == 1:
                    continue          # a header
                raise GridError(f"{path}: line {i}: class {row[0]!r} is not a whole number") from None
            try:
                out[cls] = check_material(row[1].strip(), f"{path}: line {i}: material")
            except ValueError as exc:
                raise GridError(str(exc)) from None
    if not out:
        raise GridError(f"{path}: no class,material lines")
    return out


def _open_raster(rasterio, path, where: str, what: str, crs_hint: str):
    """``rasterio.open(path)``, or one line naming ``where``: no such file (``what`` it should be),
    not a raster GDAL reads, or a raster without a CRS (``crs_hint`` says how to give it one)."""
    if not os.path.isfile(path):
        raise GridError(f"{where}: no such file ({what})")
    try:
        src = rasterio.open(path)
    except rasterio.errors.RasterioError as exc:
        raise GridError(f"{where}: not a raster GDAL reads ({first_line(exc)})") from None
    if src.crs is None:
        src.close()
        raise GridError(f"{where}: has no CRS; {crs_hint}")
    return src


def sediment_classes(path, grid: Grid, mapping: dict) -> np.ndarray:
    """The class (int) at the centre of each cell of ``grid`` ((ny-1, nx-1)), read from the
    sediment raster ``path`` (nearest cell, reprojected into the grid's CRS); refused: a cell
    outside the raster or on its nodata, a class missing from ``mapping``."""
    rasterio = _rasterio(path)
    from rasterio.transform import Affine
    from rasterio.warp import Resampling, reproject

    src = _open_raster(rasterio, path, f"--sediment {path}", "a raster of integer classes",
                       "give the file one first (gdal_edit.py -a_srs EPSG:NNNN)")
    with src:
        cx, cy = grid.x[0] + grid.cell / 2, grid.y[0] + grid.cell / 2
        ny, nx = len(grid.y) - 1, len(grid.x) - 1
        # the cells' centres as the centres of a grid of the same cell, rows down
        t = Affine(grid.cell, 0, cx - grid.cell / 2, 0, -grid.cell, cy + (ny - 0.5) * grid.cell)
        nodata = -2 ** 31
        out = np.full((ny, nx), nodata, np.int64)
        reproject(rasterio.band(src, 1), out, dst_transform=t, dst_crs=grid.crs, dst_nodata=nodata,
                  src_nodata=src.nodata, resampling=Resampling.nearest)
    out = out[::-1]
    if (out == nodata).any():
        raise GridError(f"--sediment {path}: {int((out == nodata).sum())} seabed cells have no class (outside the "
                        "raster or on its nodata); cover the seabed's area or crop it with --bounds")
    missing = sorted(set(np.unique(out).tolist()) - set(mapping))
    if missing:
        n = int(np.isin(out, missing).sum())
        raise GridError(f"--sediment {path}: class {missing[0]} ({n} cells"
                        + (f", and classes {', '.join(map(str, missing[1:]))}" if len(missing) > 1 else "")
                        + ") is not in the sediment map; add a line 'CLASS,MATERIAL' for it")
    return out


@dataclass
class GridScene:
    """What `seabed_from_grid` wrote: the scene file, its meshes, its frame and grid."""

    scene: str
    meshes: list
    frame: object
    grid: Grid
    n_vertices: int
    n_triangles: int

    def line(self) -> str:
        lod = (f", level of detail {self.grid.lod} ({2 ** self.grid.lod} x the file's cells)" if self.grid.lod else "")
        return (f"wrote {self.scene} and {len(self.meshes)} PLY: {len(self.grid.x)} x {len(self.grid.y)} vertices of "
                f"{self.grid.cell:g} m{lod}, {self.n_triangles} triangles, in {self.frame.crs} from origin "
                f"E {self.frame.e0:.3f} N {self.frame.n0:.3f}")


def grid_frame(grid: Grid, origin=None):
    """The `GeoFrame` of the scene: ``origin`` (lat, lon[, height]) or the grid's centre rounded to
    the metre (its lat/lon through the CRS)."""
    import pyproj

    from mitsonar.geometry.geodesy import GeoError, GeoFrame

    try:
        if origin is None:
            e0 = round((grid.x[0] + grid.x[-1]) / 2)
            n0 = round((grid.y[0] + grid.y[-1]) / 2)
            lon, lat = pyproj.Transformer.from_crs(grid.crs, "EPSG:4326", always_xy=True).transform(e0, n0)
            origin = (lat, lon, 0.0)
        return GeoFrame.make(origin, grid.crs)
    except GeoError as exc:
        raise GridError(str(exc)) from None


def seabed_from_grid(path, output, *, material=None, sediment=None, sediment_map=None, bounds=None,
                     resolution=None, resampling="bilinear", crs=None, positive=None, vertical_offset=0.0,
                     origin=None, sensor=None, force=False, max_vertices=MAX_VERTICES) -> GridScene:
    """Write a scene (``output``, .xml) of the seabed of grid ``path`` and its PLY meshes beside it
    (``<stem>_seabed.ply``, or ``<stem>_seabed_<material>.ply`` per sediment class); see the module
    docstring. ``sensor``: an echo-sounder preset or a ``<sensor>`` XML file (default
    ``r2sonic_2024`` looking down from the origin). Every input is checked before anything is
    written; the files are written under temporary names and renamed together. Returns a `GridScene`."""
    from mitsonar._files import StagedFiles, check_output_file
    from mitsonar.scenes import worldxml

    output = os.fspath(output)
    check_output_file(output, GridError, extensions=(".xml",), force=force)
    if (sediment is None) != (sediment_map is None):
        raise GridError("--sediment and --sediment-map go together (a class raster and its CSV class,material)")
    if sediment is not None and material is not None:
        raise GridError("--material: with --sediment the materials come from --sediment-map; give one or the other")
    try:
        material = worldxml.check_material(material or worldxml.DEFAULT_SEABED, "--material")
        sensor_text = worldxml.sensor_xml(sensor or "r2sonic_2024")
    except ValueError as exc:
        raise GridError(str(exc)) from None
    mapping = read_sediment_map(sediment_map) if sediment_map is not None else None
    grid = read_grid(path, bounds=bounds, resolution=resolution, resampling=resampling, crs=crs, positive=positive,
                     vertical_offset=vertical_offset, max_vertices=max_vertices)
    classes = sediment_classes(sediment, grid, mapping) if sediment is not None else None
    frame = grid_frame(grid, origin)
    ny, nx = grid.z.shape
    X, Y = np.meshgrid(grid.x - frame.e0, grid.y - frame.n0)
    verts = np.stack([X.ravel(), Y.ravel(), grid.z.ravel()], 1)
    faces = height_field_faces(ny, nx)
    stem = os.path.splitext(os.path.basename(output))[0]
    folder = os.path.dirname(os.path.abspath(output))
    parts = []       # (shape id, material, faces)
    if classes is None:
        parts.append(("seabed", material, faces))
    else:
        per_cell = np.concatenate([classes.ravel(), classes.ravel()])   # the two triangles of each cell
        by_material = {}
        for cls in np.unique(classes).tolist():
            by_material.setdefault(mapping[cls], []).append(cls)
        for mat, clss in sorted(by_material.items()):
            parts.append((f"seabed_{worldxml.safe_id(mat.removeprefix('seabed_'))}", mat,
                          faces[np.isin(per_cell, clss)]))
    shapes, bsdfs, meshes = [], [], []
    with StagedFiles() as files:
        for shape_id, mat, f in parts:
            name = f"{stem}_{shape_id}.ply"
            if len(parts) == 1:
                v, f = verts, f
            else:             # the part's own vertices, renumbered (a mask: np.unique sorts, 10 s at 8 M)
                used = np.zeros(len(verts), bool)
                used[f.ravel()] = True
                remap = np.cumsum(used) - 1
                v, f = verts[used], remap[f]
            worldxml.write_mesh_ply(files.temporary(os.path.join(folder, name)), v, f,
                                    comment=f"mitsonar seabed of {os.path.basename(os.fspath(path))} in {grid.crs}")
            bsdf_id = f"{shape_id}_bsdf"
            bsdfs.append(worldxml.bsdf_xml(mat, bsdf_id))
            shapes.append(worldxml.ply_shape(shape_id, name, bsdf_id))
            meshes.append(os.path.join(folder, name))
        text = worldxml.scene_text(shapes, bsdfs, frame, sensor_text)
        with open(files.temporary(output), "w", encoding="utf-8") as fh:
            fh.write(text)
    return GridScene(output, meshes, frame, grid, len(verts), len(faces))
