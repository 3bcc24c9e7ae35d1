"""Refracted transport benchmark (issue 40, speed): one 256-beam echo-sounder ping over a flat seabed
through a 20-layer sound-speed profile, against the straight-ray ping in uniform water, in one run.

Prints one JSON object:
  * ``straight``: render seconds per ping (warm: the best of ``--repeats`` renders after one that
    compiles) in uniform water at the head's nominal speed, and the per-beam range error of the
    echo peak against the straight-ray closed form ``(D - h) / cos(angle)`` (median and max of
    |error| in bins, beams whose seabed echo is inside the window);
  * ``refracted``: per ``svp_chords`` (chords per range window, `plugins/refraction.py`), the same
    two numbers through the profile, the error against the closed form
    ``c_sensor * SoundSpeedProfile.trace(h, 90 deg - angle, to_depth=D).time`` (an exact arc per
    layer), ``time_ratio`` (refracted / straight seconds, same spp, same run) and
    ``ratio_at_equal_noise``: ``time_ratio * (noise / straight noise)^2``, the cost ratio at equal
    Monte Carlo error (``noise``: the relative rms difference of two seeds' scans over the echo);
  * ``profile``: the 20 samples (a warm mixed layer over a thermocline, m and m/s).

The straight multibeam render shares each frame's paths between the beams (`shared_beams`); a
refracted one traces per-row paths (a shared echo is scored by its straight direction), so its
noise at equal spp differs: ``ratio_at_equal_noise`` compares them at equal error. The chord
approximation is the only bias: its cost in accuracy is the refracted ``median_bins`` and
``max_bins`` against the straight render's, per chord count.

Usage: python benchmarks/svp.py [--spp 256] [--repeats 3] [--depth 40]
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
from mitsonar.acoustics.profile import SoundSpeedProfile
from mitsonar.scenes import echosounders

HEAD = 2.0


def profile20():
    """A 20-sample summer profile: mixed layer 1520 m/s down to 10 m, a thermocline to 1490 m/s
    at 40 m, then slowly rising (m, m/s)."""
    d = np.array([0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 23, 26, 29, 32, 35, 40, 50, 70, 100], float)
    c = np.interp(d, [0, 10, 40, 100], [1520.0, 1519.0, 1490.0, 1491.0])
    return SoundSpeedProfile(d, c)


def scene_for(head, depth, chords=None):
    floor = np.diag([2000.0, 2000.0, 1.0, 1.0])
    floor[2, 3] = -depth
    m = " ".join(f"{v:.17g}" for v in floor.ravel())
    extra = "" if chords is None else f'<integer name="svp_chords" value="{chords}"/>'
    xml = ('<scene version="3.0.0"><integrator type="sonar_tof"><integer name="max_depth" value="1"/>'
           f'{extra}</integrator>{echosounders.sonar_xml(head)}'
           f'<shape type="rectangle"><transform name="to_world"><matrix value="{m}"/></transform>'
           '<bsdf type="acoustic"><float name="diffuse" value="0.5"/><float name="specular" value="0"/></bsdf></shape></scene>')
    return mitsonar.load_scene(xml)


def timed(scene, pose, spp, repeats, profile):
    """(best seconds of ``repeats`` warm renders, the last scan, the Monte Carlo noise): the noise
    is the rms difference of two renders of other seeds over the rms of their mean, on the bins
    holding the seabed echo (its relative standard error, times sqrt 2)."""
    first = mitsonar.render_scan(scene, spp=spp, seed=0, pose=pose, sound_speed_profile=profile)    # compiles
    best, scan = math.inf, None
    for r in range(repeats):
        t0 = time.perf_counter()
        scan = mitsonar.render_scan(scene, spp=spp, seed=r + 1, pose=pose, sound_speed_profile=profile)
        best = min(best, time.perf_counter() - t0)
    a, b = first.intensity.astype(float), scan.intensity.astype(float)
    mean = 0.5 * (a + b)
    echo = mean > 1e-2 * mean.max(axis=1, keepdims=True)
    noise = float(np.sqrt(np.mean((a - b)[echo] ** 2)) / np.sqrt(np.mean(mean[echo] ** 2)))
    return best, scan, noise


def peak_errors(scan, expected):
    peak = scan.ranges[np.argmax(scan.intensity, axis=1)]
    inside = (expected < scan.range_max - 0.5) & (scan.intensity.max(axis=1) > 0)
    bins = np.abs(peak - expected)[inside] / (scan.ranges[1] - scan.ranges[0])
    return dict(median_bins=float(np.median(bins)), max_bins=float(bins.max()), beams=int(inside.sum()))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--depth", type=float, default=40.0)
    args = ap.parse_args(argv)
    head = echosounders.configure("r2sonic_2024", n_beams=256, range_max=100.0, bin_width=0.1)
    pose = np.array(head.mount, float)
    pose[2, 3] = -HEAD
    svp = profile20()
    c_s = head.params["sound_speed"]
    scene = scene_for(head, args.depth)
    t_straight, scan, n_straight = timed(scene, pose, args.spp, args.repeats, None)
    bore = scan.poses[:, :3, 2]
    ang = np.arccos(np.clip(-bore[:, 2], -1.0, 1.0))
    straight = dict(seconds=t_straight, noise=n_straight, **peak_errors(scan, (args.depth - HEAD) / np.cos(ang)))
    exact = c_s * np.array([svp.trace(HEAD, math.pi / 2 - a, to_depth=args.depth, samples=0).time[-1] for a in ang])
    refracted = {}
    for chords in (1, 2, 4, 16):
        t, scan, noise = timed(scene_for(head, args.depth, chords), pose, args.spp, args.repeats, svp)
        # variance falls as 1/spp: the time to the straight render's noise is t (noise / n_straight)^2
        refracted[str(chords)] = dict(seconds=t, noise=noise, time_ratio=t / t_straight,
                                      ratio_at_equal_noise=t / t_straight * (noise / n_straight) ** 2,
                                      **peak_errors(scan, exact))
    print(json.dumps(dict(spp=args.spp, beams=256, depth=args.depth, head_depth=HEAD, sound_speed=c_s,
                          machine=platform.machine(), python=sys.version.split()[0], cpus=os.cpu_count(),
                          straight=straight, refracted=refracted,
                          profile=dict(depth=svp.depths.tolist(), sound_speed=svp.speeds.tolist())), indent=1))


if __name__ == "__main__":
    main()
