"""Speed of strip-map SAS backprojection (`mitsonar.sas.form_image`): prints JSON.

The target of issue 61: a 100 m x 50 m image at 2 cm pixels from one minute of pings, formed on 2
cores in under 10 minutes. The configuration: 32 receivers of 4 cm (100 kHz, 30 kHz band, the
classical processed beam lambda / D = 0.375 rad), 2 m/s, a ping every 80 ms to 60 m (1.6 m of
phase centres a ping, 0.16 m advanced: DPCA-sampled), the grid 5 to 55 m across track at 3 m
altitude; a few point targets (the cost does not depend on the scene: every pixel sums every pair
whose processed beam reaches it). ``--scale s`` shrinks the track and the image's along-track
length by ``s`` (the across-track extent, hence the pairs per pixel, stays): the rate in
pixel-element-pings per second is the figure to compare; the full-size time is the full run's
pixel-pairs over it. The full-size element data take about n_pings x 32 x 4800 x upsample x 8 bytes
(1.8 GB at upsample 2): run it where that fits.

    python benchmarks/sas_speed.py [--scale 0.05] [--upsample 2] [--pixel 0.02]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import time

import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scale", type=float, default=0.05, help="fraction of the along-track length (1: full size)")
    ap.add_argument("--pixel", type=float, default=0.02, help="m")
    ap.add_argument("--upsample", type=int, default=2)
    ap.add_argument("--across", type=float, default=50.0, help="m of ground range imaged")
    args = ap.parse_args(argv)
    import mitsonar
    from mitsonar import sas
    from mitsonar.signals import PointTarget

    cfg = sas.StripMap(n_elements=32, element_length=0.04, frequency=100e3, bandwidth=30e3, speed=2.0,
                       ping_period=0.08, range_max=60.0)
    altitude, near = 3.0, 5.0
    along = 100.0 * args.scale
    # the track covers the image plus half the longest synthetic aperture each side
    half_sa = 0.5 * cfg.synthetic_aperture(near + args.across) + cfg.dpca_advance
    duration = (along + 2 * half_sa) / cfg.speed
    n_pings = int(duration / cfg.ping_period)
    scene = mitsonar.load_scene('<scene version="3.0.0"><integrator type="sonar_tof"/>'
                                + cfg.sensor_xml(n_pings=n_pings, flat=True, depression=10.0,
                                                 beamwidth_v=80.0) + "</scene>")
    targets = [PointTarget((half_sa + along * f, near + args.across * g, 0.0), 0.0)
               for f, g in ((0.25, 0.2), (0.5, 0.5), (0.75, 0.8))]
    track = cfg.track(duration + cfg.ping_period, start=(0.0, 0.0, altitude))
    t = time.perf_counter()
    echoes = mitsonar.render_echoes(scene, cfg.pulse(), elements=cfg.elements(), spp=1, trajectory=track,
                                    start_time=0.0, targets=targets)
    t_render = time.perf_counter() - t
    grid = sas.Grid(half_sa + np.arange(0.0, along, args.pixel), near + np.arange(0.0, args.across, args.pixel), 0.0)
    t = time.perf_counter()
    data = sas.compressed(echoes, args.upsample)
    t_compress = time.perf_counter() - t
    sas.form_image(echoes, sas.Grid(grid.x[:8], grid.y[:8], 0.0), data=data)      # compile once
    image = sas.form_image(echoes, grid, data=data)
    rate = image.meta["pixel_pairs_per_second"]
    full_pixels = (100.0 / args.pixel) * (50.0 / args.pixel)
    full_pairs = image.meta["pixel_pairs"] / grid.shape[0] / grid.shape[1] * full_pixels
    print(json.dumps({
        "scale": args.scale, "pixels": grid.shape, "pixel_m": args.pixel, "n_pings": n_pings,
        "n_elements": cfg.n_elements, "ping_rate_hz": 1.0 / cfg.ping_period, "range_max_m": cfg.range_max,
        "threads": os.cpu_count(), "render_echoes_s": round(t_render, 2), "compress_s": round(t_compress, 2),
        "backprojection_s": round(image.meta["seconds"], 2), "pixel_pairs": image.meta["pixel_pairs"],
        "pixel_element_pings_per_s": rate,
        "full_size_pixel_pairs_estimate": full_pairs,
        "full_size_backprojection_s_estimate": full_pairs / rate if rate > 0 else math.inf,
    }, indent=1))


if __name__ == "__main__":
    main()
