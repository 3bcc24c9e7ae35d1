#!/usr/bin/env python
"""The thesis setting mapped twice: the map alone, then with its walls refined by analysis by synthesis.

One sonar position, three orthogonal mechanical scans of a box (``scenes_xml/box.xml``, or a box of
other dimensions with ``--box``), ``HilbertMap()`` defaults (Soares 2017, ch. 4 and 5.1). The first
map's walls are cut through the sonar, fitted with a polygon, refined until their renders match the
scans (:func:`mitsonar.inverse.room.room_feedback`) and fed back into a second map as occupied
evidence. Prints one JSON document: per setting the slice Hausdorff of the map's own ridge surface
(``hilbertmap.metrics.evaluate(..., surfaces=("ridge",), surface_bounds=slab)``, as in
``tests/test_hilbertmap_thesis.py``), AUC and AUC against the water 0.1-0.3 m from the walls,
before and after feedback, the polygon's start and refined corners, and timings.

    python benchmarks/thesis_feedback.py [--settings 0,3,11,9x7x2.5:0] [--out DIR]

A setting is a render seed (the 10 x 8 m box, sonar at the origin) or ``LxWxD:seed`` (a box of
those dimensions with the sonar at (0.6, -0.4, 0), as ``benchmarks/thesis_mapping.py --box``).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

KEYS = ("ridge_slice_hausdorff", "ridge_slice_max", "ridge_slice_comp_max", "auc", "auc_band_0.1_0.3",
        "surface_p_mean")


def parse(settings: str):
    out = []
    for item in settings.split(","):
        box, _, seed = item.rpartition(":")
        try:
            out.append((box or None, int(seed)))
        except ValueError:
            raise SystemExit(f"thesis_feedback: --settings takes seeds or LxWxD:seed, comma-separated, not {item!r}") \
                from None
    return out


def run(box, seed, out_dir):
    import mitsonar
    from hilbertmap import HilbertMap
    from hilbertmap.metrics import evaluate
    from hilbertmap.testing import orthogonal_frames
    from mitsonar.inverse.room import room_feedback
    from thesis_mapping import box_xml

    origin = (0.6, -0.4, 0.0) if box else (0.0, 0.0, 0.0)
    scene = mitsonar.load_scene(box_xml(box, out_dir) if box else os.path.join(ROOT, "scenes_xml", "box.xml"))
    scans = [mitsonar.render_scan(scene, seed=seed + j, pose=T) for j, T in enumerate(orthogonal_frames(origin))]
    V, F = (np.asarray(a) for a in mitsonar.scene_mesh(scene))
    V, F = V.astype(np.float64), F.astype(np.int64)
    t0 = time.perf_counter()
    hm = HilbertMap(random_state=seed).fit(scans)
    t_first = time.perf_counter() - t0
    t0 = time.perf_counter()
    fb = room_feedback(scans, hm, seed=seed)
    t_fb = time.perf_counter() - t0
    res = {"scene": f"box {box}" if box else "scenes_xml/box.xml", "seed": seed, "sonar": list(origin),
           "first_fit_s": round(t_first, 1), "feedback_s": round(t_fb, 1),
           "refine_s": round(fb["refine"]["seconds"], 1),
           "corners_start": np.round(fb["corners_start"], 4).tolist(), "floor_start": round(fb["floor_start"], 4),
           "corners": np.round(fb["corners"], 4).tolist(), "floor": round(fb["floor"], 4),
           "loss_start": fb["refine"]["loss_start"], "loss_final": fb["refine"]["loss_final"],
           "n_wall_points": fb["n_points"]}
    for name, m in (("map", hm), ("with_feedback", fb["map"])):
        lo, hi = m.coverage_.bounds()
        slab = ([lo[0], lo[1], origin[2] - 0.5], [hi[0], hi[1], origin[2] + 0.5])
        r = evaluate(m, V, F, surfaces=("ridge",), n_surface=3000, n_free=20000, contours=False,
                     surface_bounds=slab, random_state=seed)
        res[name] = {k: round(float(r[k]), 4) for k in KEYS}
    print(f"[{res['scene']} seed {seed}] {res['map']['ridge_slice_hausdorff']} -> "
          f"{res['with_feedback']['ridge_slice_hausdorff']} m", file=sys.stderr, flush=True)
    return res


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--settings", default="0,3,11,9x7x2.5:0")
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "thesis_feedback"))
    a = ap.parse_args(argv)
    settings = parse(a.settings)
    if any(box for box, _ in settings):
        from thesis_mapping import box_xml

        os.makedirs(a.out, exist_ok=True)
        for box, _ in settings:
            if box:
                box_xml(box, a.out)  # refuses a bad size in one line before any render
    report = {"settings": [run(box, seed, a.out) for box, seed in settings]}
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
