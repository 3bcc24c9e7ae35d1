"""Bathymetry benchmark (issue 22): depth error per beam angle of the preset multibeams, on a flat
seabed against the centroid's speckle model and over the rocky slope survey scene, and the cost of
bottom detection against the render.

Prints one JSON object:
  * ``flat``: per preset, a static head 10 m over a flat sand plane, ``--pings`` pings, each with
    the scene's speckle of another ``speckle_seed`` (another set of scatterers): per 10 deg of beam
    angle the measured rms depth error, the model's (`mitsonar.products.bathymetry.predicted_rms` at the
    scan's speckle grain ``speckle_resolution``) and their ratio, ``outer_over_inner`` (rms at
    |angle| >= 45 deg over rms at |angle| <= 15 deg), and ``still_head_error_correlation``: the
    correlation over the beams of ping 0's depth errors with those of the same still head pinged
    again with another path seed (the speckle follows the scene: near 1, only Monte Carlo noise);
  * ``rocky_slope``: per preset, ``--scans`` pings of the survey along the scene's lawnmower
    track (max_depth 1; the scene's speckle, changing as the head moves): soundings, overall rms, the table per beam angle (5 deg bins), and
    ``render_s_per_ping`` / ``detect_s_per_ping`` and their ratio (measured in this one run);
  * ``altimeter``: the PA500 over the flat plane: leading-edge and centroid range minus the true
    10 m (the centroid's known long bias).

Usage: python benchmarks/bathymetry.py [--spp 256] [--pings 8] [--scans 40]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time

import numpy as np

import mitsonar
from mitsonar.products import bathymetry
from mitsonar.scenes import echosounders
from mitsonar.scenes.sea_surface import load_survey_scene

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = os.path.join(HERE, "..", "scenes_xml")


def flat_scene(head, depth=10.0):
    return mitsonar.load_scene(
        '<scene version="3.0.0"><integrator type="sonar_tof"><integer name="max_depth" value="1"/></integrator>'
        + echosounders.sonar_xml(head)
        + f'<shape type="rectangle"><transform name="to_world"><scale x="100" y="100"/><translate z="{-depth}"/>'
          '</transform><bsdf type="acoustic"><string name="preset" value="seabed_sand"/></bsdf></shape></scene>')


def flat(name, spp, pings, depth=10.0):
    head = echosounders.configure(name, range_max=40.0)
    scene = flat_scene(head, depth)
    scans = [mitsonar.render_scan(scene, spp=spp, seed=s, speckle_seed=1000 + s) for s in range(pings)]
    parts = [bathymetry.soundings(scan, speckle=True, ping=i) for i, scan in enumerate(scans)]
    # a still head pinged again (other path seed, same scatterers): its errors repeat
    again = bathymetry.soundings(mitsonar.render_scan(scene, spp=spp, seed=pings, speckle_seed=1000), speckle=True)
    e0, e1 = (-p["z"] - depth for p in (parts[0], again))
    common = np.intersect1d(parts[0]["beam"], again["beam"])
    still = float(np.corrcoef(e0[np.searchsorted(parts[0]["beam"], common)],
                              e1[np.searchsorted(again["beam"], common)])[0, 1])
    L = bathymetry.speckle_resolution(scans[0])
    s = np.concatenate(parts)
    err = -s["z"] - depth                      # measured depth (-z) minus true depth
    rows = bathymetry.error_table(s["angle"], err, np.full(len(s), depth), 10.0)
    w, b = head.sounder.rx_across, head.params["range_max"] / head.params["n_bins"]
    for row in rows:
        pred = float(bathymetry.predicted_rms(depth / math.cos(math.radians(row["angle"])), row["angle"], w, b,
                                              resolution=L))
        row.update(predicted_rms=pred, ratio=row["rms"] / pred)
    rms = lambda m: float(np.sqrt(np.mean(err[m] ** 2)))  # noqa: E731
    a = np.abs(s["angle"])
    return dict(beams=head.params["n_pings"], swath=float(head.beam_angles[-1] - head.beam_angles[0]),
                rx_across_deg=w, bin_width=b, speckle_resolution=L, soundings=int(len(s)),
                outer_over_inner=rms(a >= 45) / rms(a <= 15), still_head_error_correlation=still, per_angle=rows)


def slope(name, spp, scans):
    head = echosounders.configure(name, range_max=25.0)
    scene = load_survey_scene(os.path.join(SCENES, "rocky_slope.xml"), sonar=echosounders.sonar_xml(head))
    track = mitsonar.Trajectory.from_tum(os.path.join(SCENES, "rocky_slope_survey.tum"))
    from mitsonar.sim.survey import render_survey

    mitsonar.render_scan(scene, spp=spp, seed=0, trajectory=track)   # compile
    t_render = t_detect = 0.0
    parts = []
    scan_iter = render_survey(scene, track, spp=spp, seed=0, max_scans=scans, max_depth=1, progress=False)
    while True:
        t = time.perf_counter()
        scan = next(scan_iter, None)
        t_render += time.perf_counter() - t
        if scan is None:
            break
        t = time.perf_counter()
        parts.append(bathymetry.soundings(scan, speckle=True, ping=len(parts)))
        t_detect += time.perf_counter() - t
    s = np.concatenate(parts)
    true_z = bathymetry.true_height(scene, s["x"], s["y"], s["head_z"])
    err = true_z - s["z"]
    ok = np.isfinite(err)
    return dict(pings=len(parts), soundings=int(len(s)), rms=float(np.sqrt(np.mean(err[ok] ** 2))),
                render_s_per_ping=t_render / len(parts), detect_s_per_ping=t_detect / len(parts),
                detect_over_render=t_detect / t_render,
                per_angle=bathymetry.error_table(s["angle"], err, -true_z, 5.0))


def altimeter(spp, depth=10.0):
    head = echosounders.configure("tritech_pa500", range_max=12.0)
    scan = mitsonar.render_scan(flat_scene(head, depth), spp=spp, seed=1)
    return {m: float(bathymetry.soundings(scan, method=m)["range"][0] - depth) for m in bathymetry.METHODS}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--pings", type=int, default=8)
    ap.add_argument("--scans", type=int, default=40)
    args = ap.parse_args(argv)
    multibeams = [n for n, p in echosounders.PRESETS.items() if p.kind == "multibeam"]
    out = dict(spp=args.spp, machine=platform.machine(), python=sys.version.split()[0], variant=mitsonar.sim.variant(),
               flat={n: flat(n, args.spp, args.pings) for n in multibeams},
               rocky_slope={n: slope(n, args.spp, args.scans) for n in multibeams},
               altimeter=altimeter(16 * args.spp))
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
