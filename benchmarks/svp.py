"""Refracted transport benchmark (issue 40, speed): one 256-beam echo-sounder ping over a flat seabed
through a 20-layer sound-speed profile, against the straight-ray ping in uniform water, in one run.

Prints one JSON object:
  * ``straight``: render seconds per ping (warm: the best of ``--repeats`` renders after one that
    compiles) in uniform water at the head's nominal speed, and the per-beam range error of the
    echo peak against the straight-ray closed form ``(D - h) / cos(angle)`` (median and max of
    |error| in bins, beams whose seabed echo is inside the window);
  * ``refracted``: per ``svp_chords`` (chords per range window, `plugins/integrators/paths/refraction.py`), the same
    two numbers through the profile, the error against the closed form
    ``c_sensor * SoundSpeedProfile.trace(h, 90 deg - angle, to_depth=D).time`` (an exact arc per
    layer), ``time_ratio`` (refracted / straight seconds, same spp, same run) and
    ``ratio_at_equal_noise``: ``time_ratio * (noise / straight noise)^2``, the cost ratio at equal
    Monte Carlo error (``noise``: the relative rms difference of two seeds' scans over the echo),
    and ``chord_shift_median_bins`` / ``_max_bins``: how far each beam's echo centroid moves
    against 64 chords per window with the same seed (the same paths: the chord approximation's
    own error, free of Monte Carlo noise);
  * ``profile``: the 20 samples (m and m/s) and ``merged_samples``, how many the render keeps
    (`refraction.merge_layers`). ``--profile thermocline`` (default): a warm mixed layer over a
    linear thermocline, three linear pieces sampled at 20 depths, which merge exactly to their 4
    knots; ``--profile smooth``: a tanh thermocline at the same depths, 20 distinct gradients,
    nothing merges (the cost of crossing 20 layers).

The straight multibeam render shares each frame's paths between the beams (`shared_beams`); a
refracted one traces per-row paths (a shared echo is scored by its straight direction), so its
noise at equal spp differs: ``ratio_at_equal_noise`` compares them at equal error. The chords
and the merged layers are the only biases: their cost in accuracy is the refracted
``median_bins`` and ``max_bins`` against the straight render's, per chord count, and the
``chord_shift``.

Measured on 26 Nov 2026 (2 cores shared with other jobs, so seconds wander by 2x between runs; the ratios come
from interleaved renders of one run), default 4 chords, ``ratio_at_equal_noise``:
  thermocline: spp 1024 1.5x (time 1.5x); spp 4096 2.1x (time 2.2x);
  smooth:      spp 1024 1.7x (time 1.7x); spp 4096 2.9x (time 3.0x).
Echo peaks within 0.004 bins of the 64-chord render at every chord count (1 to 64), and the
error against the exact-arc closed form is the straight render's (median 0.25 bins, the bin
quantisation). The refracted path costs more per sample than the straight one (about 6x, the
straight render's fixed cost per ping hides it at low spp), so the ratio grows with spp.

Usage: python benchmarks/svp.py [--spp 1024] [--repeats 5] [--depth 40] [--profile thermocline|smooth]
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


def profile20_smooth():
    """The same 20 depths through a smooth thermocline (a tanh step plus the pressure term), so
    that no two layers share a gradient and none merge (`refraction.merge_layers`)."""
    d = profile20().depths
    c = 1490.0 + 14.5 * (1.0 - np.tanh((d - 22.0) / 9.0)) + 0.017 * d
    return SoundSpeedProfile(d, c)


PROFILES = {"thermocline": profile20, "smooth": profile20_smooth}


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


def timed(configs, pose, spp, repeats):
    """Per config (name -> (scene, profile)): (best seconds of ``repeats`` warm renders, the last
    scan, the Monte Carlo noise). The configs' renders are interleaved, so that a busy machine
    slows them alike. The noise is the rms difference of two renders of other seeds over the rms
    of their mean, on the bins holding the seabed echo (the relative standard error times sqrt 2)."""
    first = {k: mitsonar.render_scan(sc, spp=spp, seed=0, pose=pose, sound_speed_profile=pr)      # compiles
             for k, (sc, pr) in configs.items()}
    best, last = {k: math.inf for k in configs}, {}
    for r in range(repeats):
        for k, (sc, pr) in configs.items():
            t0 = time.perf_counter()
            last[k] = mitsonar.render_scan(sc, spp=spp, seed=r + 1, pose=pose, sound_speed_profile=pr)
            best[k] = min(best[k], time.perf_counter() - t0)
    out = {}
    for k in configs:
        a, b = first[k].intensity.astype(float), last[k].intensity.astype(float)
        mean = 0.5 * (a + b)
        echo = mean > 1e-2 * mean.max(axis=1, keepdims=True)
        noise = float(np.sqrt(np.mean((a - b)[echo] ** 2)) / np.sqrt(np.mean(mean[echo] ** 2)))
        out[k] = (best[k], last[k], noise)
    return out


def centroids(scan):
    w = scan.intensity.astype(float)
    with np.errstate(invalid="ignore", divide="ignore"):
        return (w * scan.ranges).sum(axis=1) / w.sum(axis=1)


def peak_errors(scan, expected):
    peak = scan.ranges[np.argmax(scan.intensity, axis=1)]
    inside = (expected < scan.range_max - 0.5) & (scan.intensity.max(axis=1) > 0)
    bins = np.abs(peak - expected)[inside] / (scan.ranges[1] - scan.ranges[0])
    return dict(median_bins=float(np.median(bins)), max_bins=float(bins.max()), beams=int(inside.sum()))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--depth", type=float, default=40.0)
    ap.add_argument("--profile", choices=sorted(PROFILES), default="thermocline")
    args = ap.parse_args(argv)
    head = echosounders.configure("r2sonic_2024", n_beams=256, range_max=100.0, bin_width=0.1)
    pose = np.array(head.mount, float)
    pose[2, 3] = -HEAD
    svp = PROFILES[args.profile]()
    c_s = head.params["sound_speed"]
    chord_counts = (1, 2, 4, 16, 64)
    configs = {"straight": (scene_for(head, args.depth), None)}
    configs.update({c: (scene_for(head, args.depth, c), svp) for c in chord_counts})
    runs = timed(configs, pose, args.spp, args.repeats)
    t_straight, scan, n_straight = runs["straight"]
    bore = scan.poses[:, :3, 2]
    ang = np.arccos(np.clip(-bore[:, 2], -1.0, 1.0))
    straight = dict(seconds=t_straight, noise=n_straight, **peak_errors(scan, (args.depth - HEAD) / np.cos(ang)))
    exact = c_s * np.array([svp.trace(HEAD, math.pi / 2 - a, to_depth=args.depth, samples=0).time[-1] for a in ang])
    refracted, scans = {}, {}
    for chords in chord_counts:
        t, scan, noise = runs[chords]
        scans[chords] = scan
        # variance falls as 1/spp: the time to the straight render's noise is t (noise / n_straight)^2
        refracted[str(chords)] = dict(seconds=t, noise=noise, time_ratio=t / t_straight,
                                      ratio_at_equal_noise=t / t_straight * (noise / n_straight) ** 2,
                                      **peak_errors(scan, exact))
    # the chord approximation alone: the same seed's paths with 64 chords per window as the
    # reference (same samples, so no Monte Carlo difference): echo centroid shift per beam
    ref = centroids(scans[64])
    bin_w = scans[64].ranges[1] - scans[64].ranges[0]
    for chords, scan in scans.items():
        shift = np.abs(centroids(scan) - ref) / bin_w
        ok = np.isfinite(shift)
        refracted[str(chords)].update(chord_shift_median_bins=float(np.median(shift[ok])),
                                      chord_shift_max_bins=float(shift[ok].max()))
    print(json.dumps(dict(spp=args.spp, beams=256, depth=args.depth, head_depth=HEAD, sound_speed=c_s,
                          machine=platform.machine(), python=sys.version.split()[0], cpus=os.cpu_count(),
                          straight=straight, refracted=refracted,
                          profile=dict(name=args.profile, depth=svp.depths.tolist(), sound_speed=svp.speeds.tolist(),
                                       merged_samples=merged_samples(svp))), indent=1))


def merged_samples(svp):
    """How many of the profile's samples the render keeps (`refraction.merge_layers`); None with
    a renderer that does not merge."""
    from mitsonar.plugins.integrators.paths import refraction

    merge = getattr(refraction, "merge_layers", None)
    return None if merge is None else len(merge([float(v) for v in svp.depths], [float(v) for v in svp.speeds])[0])


if __name__ == "__main__":
    main()
