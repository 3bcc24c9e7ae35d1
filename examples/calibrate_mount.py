"""Calibrate a sonar head's mounting pose from scans of a known scene (issue "Inverse problems").

A mechanical scanning head is mounted in a tank of known geometry (the thesis's box: walls at
x = +-5 m and y = +-4 m, a floor), its nominal mount a few centimetres and degrees off the true
one. The true mount is ``T = T_nominal @ D(t, r)``, ``D`` a translation ``t`` after a rotation by
the rotation vector ``r`` (both in the head's beam frame). Starting from ``D = identity`` (the
nominal mount), Adam (``mi.ad.Adam``) fits ``(t, r)`` so that the rendered noise-free scan matches
the target scan, through the derivative of ``mi.render`` with respect to the sensor's ``to_world``
(path replay, ``plugins/integrators/paths/path_replay.py``). Loss: relative L2 between the two scans blurred along
range by a Gaussian of ``blur`` bins (a pulse's spread), which turns sub-bin range errors into a
smooth loss.

The target is rendered with the seed the fit uses (common random numbers: the emitted directions
are fixed in the beam frame, so the fit sees the same rays move with the head, and the loss is 0
at the true mount); ``--target-seed`` renders it with other paths instead (then the optimum moves by
the Monte Carlo noise of the scans).

Run: ``python examples/calibrate_mount.py --out calibrate_mount.png``: prints the pose error per
iteration and writes a figure of the loss and the pose error (cm, degrees) per iteration.
"""
from __future__ import annotations

import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _inverse import argument_parser, loss_figure, positive_int, relative_l2, rotation_angle_deg, save_figure  # noqa: E402
from _inverse import small_pose  # noqa: E402
from _inverse import tank_xml as _tank_xml  # noqa: E402

# The mounting error of the example: a few centimetres and degrees (beam frame).
TRUE_T = (0.04, -0.03, 0.05)        # metres
TRUE_R_DEG = (2.0, -1.5, 3.0)       # rotation vector, degrees


def nominal_mount():
    """The nominal beam frame: transducer at (0.5, -0.3, -2.4), 0.6 m over the floor in the tank, scan axis (beam +y) up,
    boresight at bearing 0 (beam +z) along world +x (as in scenes_xml/box.xml)."""
    m = np.array([[0.0, 0.0, 1.0, 0.5],
                  [1.0, 0.0, 0.0, -0.3],
                  [0.0, 1.0, 0.0, -2.4],
                  [0.0, 0.0, 0.0, 1.0]])
    return m


def tank_xml(n_pings=24, n_bins=160, range_max=8.0, max_depth=1):
    """The calibration scene: `_inverse.tank_xml` with the head at `nominal_mount` sweeping a full
    turn in ``n_pings`` pings, one material ``wall`` (diffuse 0.5, specular 0.2, shininess 10)."""
    return _tank_xml(nominal_mount(), n_pings=n_pings, n_bins=n_bins, range_max=range_max, max_depth=max_depth,
                     walls=(0.5, 0.2, 10.0))


def pose_error(t_est, r_est, t_true=TRUE_T, r_true_deg=TRUE_R_DEG):
    """(translation error in m, rotation error in degrees) of the estimated mount ``D(t_est, r_est)``
    against the true one: the distance between the transducer positions and the angle of
    ``R_est^T R_true``."""
    import mitsuba as mi

    def mat(t, r):
        return np.asarray(small_pose(mi.Vector3f(*t), mi.Vector3f(*r)).matrix, dtype=np.float64).reshape(4, 4)

    a = mat(t_est, r_est)
    b = mat(t_true, [math.radians(v) for v in r_true_deg])
    return float(np.linalg.norm(a[:3, 3] - b[:3, 3])), rotation_angle_deg(a[:3, :3].T @ b[:3, :3])


def calibrate(iterations=100, spp=1024, seed=7, target_seed=None, n_pings=24, n_bins=160, blur=2.0,
              lr=2.0, callback=None):
    """Fit the mounting error; returns a dict with ``history`` (per iteration: loss, translation
    error m, rotation error deg), the final ``t`` (m) and ``r`` (deg) and ``seconds``.

    ``lr`` is Adam's learning rate in centimetres / degrees per step (the unknowns are scaled to
    those units), decayed geometrically to a 20th of it over the iterations."""
    import drjit as dr
    import mitsuba as mi

    import mitsonar
    from mitsonar.sim.render import scan_parameters

    iterations = positive_int("iterations", iterations, 1, 100000)
    spp = positive_int("spp", spp, 1, 1 << 24)
    scene = mitsonar.load_scene(tank_xml(n_pings=n_pings, n_bins=n_bins))
    params = scan_parameters(scene, "head.to_world")
    nominal = mi.Transform4f(params["head.to_world"])

    params["head.to_world"] = nominal @ small_pose(mi.Vector3f(*TRUE_T),
                                                   mi.Vector3f(*[math.radians(v) for v in TRUE_R_DEG]))
    params.update()
    target = mi.render(scene, spp=spp, seed=seed if target_seed is None else target_seed)
    dr.eval(target)

    opt = mi.ad.Adam(lr=lr)
    opt["t_cm"] = mi.Vector3f(0.0)
    opt["r_deg"] = mi.Vector3f(0.0)
    history = []
    t0 = time.perf_counter()
    decay = 0.05 ** (1.0 / max(1, iterations - 1))
    for it in range(iterations):
        t = opt["t_cm"] * 0.01
        r = opt["r_deg"] * (math.pi / 180.0)
        params["head.to_world"] = nominal @ small_pose(t, r)
        params.update()
        img = mi.render(scene, params, spp=spp, seed=seed)
        loss = relative_l2(img, target, blur)
        dr.backward(loss)
        t_np = [float(v) * 0.01 for v in np.asarray(opt["t_cm"]).ravel()]
        r_np = [math.radians(float(v)) for v in np.asarray(opt["r_deg"]).ravel()]
        et, er = pose_error(t_np, r_np)
        history.append((float(loss[0]), et, er))
        if callback is not None:
            callback(it, history[-1])
        opt.step()
        opt.set_learning_rate(lr * decay ** (it + 1))
    seconds = time.perf_counter() - t0
    t_fin = [float(v) * 0.01 for v in np.asarray(opt["t_cm"]).ravel()]
    r_fin = [float(v) for v in np.asarray(opt["r_deg"]).ravel()]
    et, er = pose_error(t_fin, [math.radians(v) for v in r_fin])
    return {"history": history, "t": t_fin, "r_deg": r_fin, "translation_error_m": et,
            "rotation_error_deg": er, "seconds": seconds, "iterations": iterations}


def figure(result, path):
    fig, right, h, it = loss_figure(result["history"], "relative L2 loss")
    right.plot(it, 100 * h[:, 1], label="translation error (cm)")
    right.plot(it, h[:, 2], label="rotation error (deg)")
    right.axhline(1.0, color="0.6", lw=0.8, ls="--")
    right.axhline(0.2, color="0.6", lw=0.8, ls=":")
    right.set_xlabel("iteration")
    right.legend()
    fig.suptitle("Mount calibration from scans of a known tank")
    save_figure(fig, path)


def main(argv=None):
    a = argument_parser(__doc__, "calibrate_mount.png", iterations=100, seed=7).parse_args(argv)

    def show(it, h):
        print(f"iter {it:3d}  loss {h[0]:.3e}  translation error {100 * h[1]:6.2f} cm  rotation error {h[2]:5.2f} deg")

    res = calibrate(iterations=a.iterations, spp=a.spp, seed=a.seed, target_seed=a.target_seed, callback=show)
    print(f"final: translation error {100 * res['translation_error_m']:.2f} cm, rotation error "
          f"{res['rotation_error_deg']:.3f} deg after {res['iterations']} iterations, {res['seconds']:.1f} s")
    figure(res, a.out)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
