"""A large bathymetric grid as a scene (issue 60): a 4000 x 4000 GeoTIFF (0.5 m cells, a
2 x 2 km site in UTM 31N, an analytic slope with ridges) converted by ``mitsonar scene from-grid``
(its level of detail: the cell doubled until the mesh fits the terrain's 8 M-vertex cap), loaded by
``mitsonar.load_scene``, and one 512-beam multibeam frame rendered on ``--threads`` threads.

Prints one JSON object: the grid's size, the mesh's vertices, triangles and level of detail, the
seconds of the GeoTIFF's writing (not counted), the conversion and the load, their sum, the
frame's render seconds, and the process's peak resident memory (``ru_maxrss``) after the
conversion, after the load and at the end (the three steps run in this one process).

Usage: python benchmarks/grid_scene.py [--size 4000] [--threads 2] [--spp 16] [--folder DIR]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import sys
import tempfile
import time

import numpy as np


def make_grid(path, n, cell=0.5, e0=431000.0, n0=5761000.0):
    import rasterio
    from rasterio.transform import from_origin

    with rasterio.open(path, "w", driver="GTiff", width=n, height=n, count=1, dtype="float32", crs="EPSG:32631",
                       transform=from_origin(e0, n0 + n * cell, cell, cell), tiled=True) as dst:
        for r0 in range(0, n, 500):
            rows = np.arange(r0, min(n, r0 + 500))
            y = (n - rows - 0.5)[:, None] * cell
            x = (np.arange(n) + 0.5)[None, :] * cell
            z = -30.0 + 0.01 * x + 1.5 * np.sin(x / 40.0) * np.cos(y / 55.0)
            dst.write(z.astype(np.float32), 1, window=rasterio.windows.Window(0, r0, n, len(rows)))
        dst.set_band_description(1, "elevation")


def peak_gb():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 ** 2   # KiB on Linux


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--size", type=int, default=4000)
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--spp", type=int, default=16)
    p.add_argument("--folder", help="work folder (default a temporary one)")
    a = p.parse_args(argv)
    folder = a.folder or tempfile.mkdtemp(prefix="grid_scene_")
    tif, xml = os.path.join(folder, "site.tif"), os.path.join(folder, "site.xml")
    t = time.perf_counter()
    make_grid(tif, a.size)
    t_make = time.perf_counter() - t

    import drjit as dr

    import mitsonar
    from mitsonar.scenes import seabed_from_grid, worldxml

    dr.set_thread_count(a.threads)
    head = os.path.join(folder, "head.xml")
    with open(head, "w") as f:      # 512 beams over 120 deg, looking down from 5 m below the surface
        f.write(worldxml.sensor_xml("r2sonic_2024").replace('name="n_pings" value="256"', 'name="n_pings" value="512"')
                .replace('name="bearing_step" value="0.50980392156862742"', 'name="bearing_step" value="0.23483365949119372"')
                .replace('name="bearing_start" value="-65"', 'name="bearing_start" value="-60"')
                .replace('value="0 1 0 0 1 0 0 0 0 0 -1 0 0 0 0 1"', 'value="0 1 0 0 1 0 0 0 0 0 -1 -5 0 0 0 1"'))
    t = time.perf_counter()
    site = seabed_from_grid(tif, xml, sensor=head, force=True)
    t_convert = time.perf_counter() - t
    mem_convert = peak_gb()
    t = time.perf_counter()
    scene = mitsonar.load_scene(xml)
    t_load = time.perf_counter() - t
    mem_load = peak_gb()
    t = time.perf_counter()
    scan = mitsonar.render_scan(scene, spp=a.spp, seed=0)
    t_render = time.perf_counter() - t
    out = {
        "grid": [a.size, a.size], "cell_m": 0.5, "mesh_vertices": site.n_vertices, "mesh_triangles": site.n_triangles,
        "level_of_detail": site.grid.lod, "mesh_cell_m": site.grid.cell,
        "ply_mb": round(sum(os.path.getsize(m) for m in site.meshes) / 1e6, 1),
        "write_geotiff_s": round(t_make, 2), "convert_s": round(t_convert, 2), "load_s": round(t_load, 2),
        "convert_plus_load_s": round(t_convert + t_load, 2), "render_frame_s": round(t_render, 2),
        "beams": scan.n_pings, "spp": a.spp, "threads": a.threads,
        "peak_rss_gb_after_convert": round(mem_convert, 2), "peak_rss_gb_after_load": round(mem_load, 2),
        "peak_rss_gb": round(peak_gb(), 2), "echo_sum": float(np.asarray(scan.intensity).sum()),
        "python": sys.version.split()[0], "machine": platform.machine(), "cpus": os.cpu_count(),
        "load_avg": [round(v, 2) for v in os.getloadavg()],
    }
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
