"""Inverse-problem benchmark (issue "Inverse problems"): what each example reaches, in how many
iterations and how much time, and the bias the geometry gradients leave.

Prints one JSON object, everything measured in this one run:
  * ``calibrate_mount``: translation (m) and rotation (deg) error of the fitted mount, from the
    start's (the nominal mount), after ``iterations`` Adam steps; ``seconds`` of the fit, and
    ``seconds_per_iteration`` (a render and its backward pass per step).
  * ``recover_reflectance``: the largest relative error of the six fitted BSDF parameters, from
    the start's.
  * ``recover_seabed``: the RMS height error (m) over the cells the pings see, from the flat start's,
    and their ratio ``error_reduction``.
  * ``geometry_bias``: the vertex-position derivative of the seabed example's loss (one ping)
    along a few directions (towards the true terrain, and smooth random fields), by path replay
    and by central finite differences of the primal renderer with the same paths; ``ratio`` =
    replay / finite difference; at the flat start (coplanar facets: no normal jumps) and halfway to
    the true terrain (facets at angles: the departure from 1 is what the facet edges the derivative
    does not follow leave, as a facet's normal jumps at its edges and moving vertices moves the
    jumps across the beam).

Usage: python benchmarks/inverse.py [--quick]  (``--quick``: the tests' sizes)
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "examples"))


def calibrate(quick):
    import calibrate_mount as cm

    res = cm.calibrate(iterations=70 if quick else 100)
    h = res["history"]
    return {"iterations": res["iterations"], "seconds": round(res["seconds"], 2),
            "seconds_per_iteration": round(res["seconds"] / res["iterations"], 3),
            "start_translation_error_m": round(h[0][1], 4), "start_rotation_error_deg": round(h[0][2], 3),
            "translation_error_m": round(res["translation_error_m"], 5),
            "rotation_error_deg": round(res["rotation_error_deg"], 4)}


def reflectance(quick):
    import recover_reflectance as rr

    res = rr.recover(iterations=100)
    start = max(abs(v - res["truth"][k]) / res["truth"][k] for k, v in zip(res["keys"], res["history"][0][1:]))
    return {"iterations": res["iterations"], "seconds": round(res["seconds"], 2),
            "seconds_per_iteration": round(res["seconds"] / res["iterations"], 3),
            "start_largest_relative_error": round(start, 3),
            "largest_relative_error": round(max(res["relative_errors"].values()), 4),
            "relative_errors": {k: round(v, 4) for k, v in res["relative_errors"].items()}}


def seabed(quick):
    import recover_seabed as rs

    res = rs.recover(iterations=30 if quick else 60)
    return {"iterations": res["iterations"], "pings": res["pings"], "seconds": round(res["seconds"], 2),
            "seconds_per_iteration": round(res["seconds"] / res["iterations"], 3),
            "rms_start_m": round(res["rms_start"], 4), "rms_final_m": round(res["rms_final"], 4),
            "error_reduction": round(res["rms_start"] / res["rms_final"], 2)}


def geometry_bias(spp=8192, h=0.05, n_random=3):
    import drjit as dr
    import mitsuba as mi
    import numpy as np

    import mitsonar
    import recover_seabed as rs
    from _inverse import relative_l2
    from mitsonar.sim.render import scan_parameters

    nx, ny = 9, 25
    z_true, x, y = rs.true_heights(nx, ny, 0.5)
    Vt, F = rs.grid_mesh(x, y, z_true)
    Vf, _ = rs.grid_mesh(x, y, np.full_like(z_true, rs.DEPTH))
    with tempfile.TemporaryDirectory() as tmp:
        ply = os.path.join(tmp, "seabed.ply")
        rs.write_ply(ply, Vf, F)
        scene = mitsonar.load_scene(rs.survey_xml(ply))
    params = scan_parameters(scene, ["head.to_world", "seabed.vertex_positions"])
    key = "seabed.vertex_positions"
    params["head.to_world"] = mi.Transform4f(mi.Matrix4f(rs.head_poses([0.25], 2.0)[0]))
    params[key] = mi.Float(Vt.ravel())
    params.update()
    target = mi.render(scene, spp=spp, seed=5)
    dr.eval(target)
    bases = {"flat_start": mi.Float(Vf.ravel()), "halfway": mi.Float((Vf + 0.5 * (Vt - Vf)).ravel())}
    rng = np.random.default_rng(0)
    directions = {"towards_truth": (Vt - Vf).ravel()}
    X, Y = np.meshgrid(x, y, indexing="ij")
    for i in range(n_random):
        kx, ky, ph = rng.uniform(0.3, 1.2), rng.uniform(0.3, 1.2), rng.uniform(0, 2 * np.pi)
        d = np.zeros_like(Vf)
        d[:, 2] = (0.1 * np.sin(kx * X + ky * Y + ph)).ravel()
        directions[f"smooth_random_{i}"] = d.ravel()
    out = {}
    for (where, base), (name, d) in ((b, dd) for b in bases.items() for dd in directions.items()):
        D = mi.Float(d.astype(np.float32))

        def loss_at(v):
            params[key] = base + v * D
            params.update()
            return float(relative_l2(mi.render(scene, spp=spp, seed=5), target, 1.5)[0])

        fd = (loss_at(h) - loss_at(-h)) / (2 * h)
        s = mi.Float(0.0)
        dr.enable_grad(s)
        params[key] = base + s * D
        params.update()
        dr.backward(relative_l2(mi.render(scene, params, spp=spp, seed=5), target, 1.5))
        g = float(dr.grad(s)[0])
        out.setdefault(where, {})[name] = {"replay": round(g, 6), "finite_difference": round(fd, 6), "ratio": round(g / fd, 3)}
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="the tests' sizes")
    a = ap.parse_args(argv)
    import mitsonar  # noqa: F401  (variant and plugins)
    import mitsuba as mi

    result = {"machine": {"cpu": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
                          "variant": mi.variant()},
              "calibrate_mount": calibrate(a.quick), "recover_reflectance": reflectance(a.quick),
              "recover_seabed": seabed(a.quick), "geometry_bias": geometry_bias()}
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
