"""Frame profile (issue 55): where one frame's time goes, stage by stage, with ``dr.sync_thread``
between the stages, for the frame at spp 1 (its fixed cost) and at a spp near 5 % error.

Prints one JSON object. Per case (the 512-beam quay-wall frame, the 200-ping box scan, a one-row
ping of the live harbour head turning 1.8 deg a ping, a side-scan ping pair) and per spp, frames
are rendered interleaved (spp 1, spp N, spp 1, ...; the machine is shared) and each stage timed
after the previous one's kernels finished:

  render      `render_histogram_device`: the integrator's set-up, frozen passes, kernels and
              the passes' mean with its float32 (the frame's intensity), left on the device
  speckle     `Electronics.scene_speckle_field` (a still head's field comes from the cache)
  chain       `Electronics.device_bytes`: the noise draws and the chain's kernel
  copy_out    the intensity's and the bytes' ``.numpy()`` (`render_scan`'s one transfer)
  frame       the whole `render_scan` (argument checks, metadata and `Scan` included), timed
              separately; ``other`` is frame minus the stages above

plus the frame's CPU time (user + system, ``resource.getrusage``) and the load average. The
stages are the ones `render_frame` runs (mitsonar/sim/render.py), called here one by one.

Usage: python benchmarks/frame_profile.py [--frames 9] [--spp 250] [--quick]
"""
from __future__ import annotations

import argparse
import itertools
import json
import math
import os
import resource
import statistics
import tempfile
import time

import numpy as np

import mitsonar  # noqa: F401  (selects the variant and registers the plugins)
import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

from mitsonar.receiver.electronics import Electronics  # noqa: E402
from mitsonar.sim.variant import ensure_variant  # noqa: E402

ensure_variant()
from mitsonar.sim import render as render_mod  # noqa: E402
from mitsonar.sim.scene import load_scene  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = os.path.join(HERE, "..", "scenes_xml")
STAGES = ("render", "speckle", "chain", "copy_out")


def _scene(path, edits=None):
    full = os.path.join(SCENES, path)
    if not edits:
        return load_scene(full)
    text = open(full).read()
    for a, b in edits.items():
        assert a in text, (path, a)
        text = text.replace(a, b)
    with tempfile.NamedTemporaryFile("w", suffix=".xml", dir=SCENES, delete=False) as f:
        f.write(text)
    try:
        return load_scene(f.name)
    finally:
        os.unlink(f.name)


def _cpu():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def staged_frame(scene, sonar, spp, seed, pose):
    """Seconds per stage of one frame (the stages of `render_frame`, synchronised between)."""
    integ = scene.integrator()
    model = Electronics.from_dict(dict(sonar.electronics))
    ranges = sonar.bin_centres()
    t = {}
    shape = (int(sonar.n_pings), int(sonar.n_bins))
    t0 = time.perf_counter()
    _, inten = integ.render_histogram_device(scene, sonar, seed=seed, spp=spp, pose=pose)
    dr.sync_thread()
    t2 = time.perf_counter()
    t["render"] = t2 - t0
    poses = sonar.ping_poses(pose)
    field = model.scene_speckle_field(poses, ranges, **render_mod.speckle_geometry(sonar))
    dr.sync_thread()
    t3 = time.perf_counter()
    t["speckle"] = t3 - t2
    data = model.device_bytes(inten, shape, ranges, absorption=sonar.absorption,
                              sound_speed=sonar.sound_speed, seed=seed, speckle=field)
    dr.sync_thread()
    t4 = time.perf_counter()
    t["chain"] = t4 - t3
    inten.numpy()
    data.numpy()
    t["copy_out"] = time.perf_counter() - t4
    return t


def profile(name, scene, spps, frames, poses):
    """Interleaved frames of ``scene`` at each of ``spps``; ``poses``: an iterator of poses (None: still)."""
    sonar = scene.sensors()[0]
    for spp in spps:   # compile and record before timing
        render_mod.render_scan(scene, spp=spp, seed=0, pose=next(poses), sensor=sonar)
        staged_frame(scene, sonar, spp, 0, next(poses))
    acc = {spp: {"stages": {k: [] for k in STAGES}, "frame": [], "cpu": []} for spp in spps}
    for i in range(frames):
        for spp in spps:
            a = acc[spp]
            for k, v in staged_frame(scene, sonar, spp, 1 + i, next(poses)).items():
                a["stages"][k].append(v)
            c0, t0 = _cpu(), time.perf_counter()
            render_mod.render_scan(scene, spp=spp, seed=1 + i, pose=next(poses), sensor=sonar)
            a["frame"].append(time.perf_counter() - t0)
            a["cpu"].append(_cpu() - c0)
    out = {"rows": int(sonar.n_pings), "bins": int(sonar.n_bins)}
    for spp in spps:
        a = acc[spp]
        med = {k: statistics.median(v) * 1e3 for k, v in a["stages"].items()}
        frame = statistics.median(a["frame"]) * 1e3
        out[f"spp_{spp}"] = {"frame_ms_median": round(frame, 2),
                             "frame_cpu_ms_median": round(statistics.median(a["cpu"]) * 1e3, 2),
                             "stages_ms_median": {k: round(v, 3) for k, v in med.items()},
                             "other_ms": round(frame - sum(med.values()), 3)}
    if len(spps) == 2:
        lo, hi = (out[f"spp_{s}"]["frame_ms_median"] for s in spps)
        out["fixed_cost_share"] = round(lo / hi, 4)   # the frame at spp 1 over the frame at spp N
    print(f"# {name}: {json.dumps(out)}", flush=True)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=9)
    ap.add_argument("--spp", type=int, default=250, help="the quay frame's spp near 5 %% error (max_depth 3)")
    ap.add_argument("--quick", action="store_true", help="3 frames, the quay frame and the live ping only")
    args = ap.parse_args(argv)
    frames = 3 if args.quick else args.frames
    out = {"variant": mi.variant(), "dr_threads": dr.thread_count(), "cores": os.cpu_count(),
           "load_avg_start": os.getloadavg(), "frames": frames}
    still = itertools.repeat(None)
    out["quay_frame"] = profile("quay_frame", _scene("quay_wall.xml"), (1, args.spp), frames, still)

    from mitsonar.live.heads import live_scene
    from mitsonar.geometry.frames import bearing_rotation

    harbour = live_scene(os.path.join(SCENES, "harbour.xml"))
    mount = np.array(harbour.sensors()[0].to_world_np, dtype=np.float64)
    turning = (mount @ bearing_rotation(math.radians(1.8 * (k % 200))) for k in itertools.count())
    out["live_ping"] = profile("live_ping", harbour, (1, 16), frames, turning)
    if not args.quick:
        out["box_scan"] = profile("box_scan", _scene("box.xml"), (1, 256), frames, still)
        pair = _scene("wreck_sidescan.xml", {'name="n_pings" value="250"': 'name="n_pings" value="1"'})
        out["sidescan_ping_pair"] = profile("sidescan_ping_pair", pair, (1, 256), frames, still)
    out["load_avg_end"] = os.getloadavg()
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
