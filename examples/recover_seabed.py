"""Recover a seabed height map from the side-scan pings of a short survey (issue "Inverse problems").

Shape from shading with the true physics: a side-scan head (``kind="sidescan"``, both channels)
runs along x at ``altitude`` over a small height-map mesh (``face_normals``: one normal a facet)
and pings every ``spacing`` metres. Starting from a flat seabed at the nominal depth, Adam
(``mi.ad.Adam``) fits the heights of the mesh's vertices so that the rendered pings match the
target pings, through the derivative of ``mi.render`` with respect to ``<mesh>.vertex_positions``
(the echoes' ranges and incidence angles; ``plugins/integrators/paths/path_replay.py``). A side-scan ping constrains
the seabed's across-track slope through the echo intensity (shading) and its height through the
range. One ping's strip (2 deg along track) crosses each cell row once, so it sees an average of
the vertices on either side: the heights are parametrised as ``z = DEPTH + S u`` with ``S`` a
Gaussian blur of ``sigma`` vertices (Adam steps on ``u`` are smooth height changes), and a small
Laplacian penalty ``smooth * sum (laplacian z)^2`` fills what the pings do not see (the nadir gap
under the track, the mesh's border).

Loss per ping: relative L2 between the range-blurred noise-free intensities (``_inverse.relative_l2``),
summed over the pings; each ping is rendered and back-propagated on its own (the head's pose is a
scene parameter), so memory is that of one ping. The targets are rendered with the seeds the fit
uses (common random numbers).

What the derivative leaves out (a bias, measured by ``benchmarks/inverse.py``): a facet's normal
jumps at its edges, and moving vertices moves those jumps across the beam; facet edges and
silhouettes are not differentiated.

Run: ``python examples/recover_seabed.py --out recover_seabed.png``: prints the loss and the RMS
height error (over the cells the pings see) per iteration and writes a figure of the true,
starting and recovered height maps and of the error per iteration.
"""
from __future__ import annotations

import os
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _inverse import argument_parser, positive_int, pyplot, relative_l2, save_figure  # noqa: E402

# The height map as a mesh and its binary PLY, the Gaussian smoothing of the heights and the
# Laplacian penalty: the library's (`mitsonar.inverse.height_field`, which refines such height fields
# coarse-to-fine).
from mitsonar.inverse.driver import write_ply  # noqa: E402
from mitsonar.inverse.height_field import grid_mesh, laplacian_penalty, smoothed, smoothing_taps  # noqa: E402,F401

DEPTH = -2.0


def true_heights(nx, ny, spacing, amplitude=0.25):
    """The terrain to recover: two smooth mounds and a trough on the nominal depth (m)."""
    x = (np.arange(nx) - (nx - 1) / 2) * spacing
    y = (np.arange(ny) - (ny - 1) / 2) * spacing
    X, Y = np.meshgrid(x, y, indexing="ij")
    z = (np.exp(-((X - 0.8) ** 2 + (Y - 2.5) ** 2) / 1.2) - 0.8 * np.exp(-((X + 0.5) ** 2 + (Y + 3.0) ** 2) / 1.5)
         + 0.6 * np.exp(-((X + 1.0) ** 2 + (Y - 4.5) ** 2) / 0.8))
    return DEPTH + amplitude * z, x, y


def survey_xml(ply, n_bins=120, range_max=8.0, depression=30.0):
    return ('<scene version="3.0.0"><integrator type="sonar_tof"><integer name="max_depth" value="1"/></integrator>'
            '<sensor type="sonar" id="head"><string name="kind" value="sidescan"/><string name="side" value="both"/>'
            f'<integer name="n_pings" value="1"/><float name="depression" value="{depression}"/>'
            f'<float name="range_min" value="0"/><float name="range_max" value="{range_max}"/>'
            f'<integer name="n_bins" value="{n_bins}"/><float name="beamwidth_h" value="2"/>'
            '<float name="beamwidth_v" value="50"/></sensor>'
            '<bsdf type="acoustic" id="sand"><float name="diffuse" value="0.4"/><float name="specular" value="0.05"/>'
            '<float name="shininess" value="5"/></bsdf>'
            f'<shape type="ply" id="seabed"><string name="filename" value="{ply}"/>'
            '<boolean name="face_normals" value="true"/><ref id="sand"/></shape></scene>')


def head_poses(x_pings, altitude):
    """Head frames (x along track, y port, z up) at ``(x, 0, DEPTH + altitude)`` for each ping."""
    out = []
    for x in x_pings:
        m = np.eye(4)
        m[:3, 3] = (x, 0.0, DEPTH + altitude)
        out.append(m)
    return out


def recover(iterations=30, spp=1024, seed=3, nx=9, ny=25, spacing=0.5, altitude=2.0, pings=None, blur=1.5,
            lr=0.04, smooth=0.5, sigma=1.0, callback=None):
    """Fit the vertex heights; returns a dict with ``history`` (loss, RMS height error over the seen
    vertices per iteration), ``rms_start``, ``rms_final``, ``heights`` (true, recovered), ``x``,
    ``y``, ``seen`` (mask) and ``seconds``. ``pings``: along-track positions (default: the middle of
    every cell along x). Seen vertices: ``1.2 <= |y| <= 5`` m (outside the nadir gap, a metre in from the
    mesh's border)."""
    import drjit as dr
    import mitsuba as mi

    import mitsonar
    from mitsonar.sim.render import scan_parameters

    iterations = positive_int("iterations", iterations, 1, 100000)
    spp = positive_int("spp", spp, 1, 1 << 24)
    nx, ny = positive_int("nx", nx, 3, 400), positive_int("ny", ny, 3, 400)
    if not (spacing > 0 and altitude > 0):
        raise SystemExit(f"spacing, altitude: {spacing!r}, {altitude!r} are not allowed (lengths > 0 in metres)")
    z_true, x, y = true_heights(nx, ny, spacing)
    if pings is None:
        pings = (x[:-1] + x[1:]) / 2
    V_true, F = grid_mesh(x, y, z_true)
    V_flat, _ = grid_mesh(x, y, np.full_like(z_true, DEPTH))
    with tempfile.TemporaryDirectory() as tmp:
        ply = os.path.join(tmp, "seabed.ply")
        write_ply(ply, V_flat, F)
        scene = mitsonar.load_scene(survey_xml(ply))
    params = scan_parameters(scene, ["head.to_world", "seabed.vertex_positions"])
    key = "seabed.vertex_positions"
    poses = [mi.Transform4f(mi.Matrix4f(m)) for m in head_poses(pings, altitude)]

    params[key] = mi.Float(V_true.ravel())
    params.update()
    targets = []
    for k, pose in enumerate(poses):
        params["head.to_world"] = pose
        params.update()
        t = mi.render(scene, spp=spp, seed=seed + k)
        dr.eval(t)
        targets.append(t)

    xy = mi.Float(np.where(np.arange(V_flat.size) % 3 == 2, 0.0, V_flat.ravel()).astype(np.float32))
    zsel = mi.Float((np.arange(V_flat.size) % 3 == 2).astype(np.float32))
    vid = dr.arange(mi.UInt32, V_flat.size) // 3
    seen = (np.abs(y)[None, :] >= 1.2) & (np.abs(y)[None, :] <= 5.0) & np.ones((nx, 1), bool)

    def rms(z):
        return float(np.sqrt(np.mean((z - z_true)[seen] ** 2)))

    taps = smoothing_taps(nx, ny, sigma)
    opt = mi.ad.Adam(lr=lr)
    opt["u"] = dr.zeros(mi.Float, nx * ny)
    history = []
    t0 = time.perf_counter()
    decay = 0.2 ** (1.0 / max(1, iterations - 1))
    for it in range(iterations):
        total = 0.0
        for k, pose in enumerate(poses):
            params["head.to_world"] = pose
            dz = smoothed(opt["u"], taps, nx * ny)
            params[key] = xy + zsel * (DEPTH + dr.gather(mi.Float, dz, vid))
            params.update()
            img = mi.render(scene, params, spp=spp, seed=seed + k)
            loss = relative_l2(img, targets[k], blur)
            dr.backward(loss)
            total += float(loss[0])
        reg = smooth * laplacian_penalty(smoothed(opt["u"], taps, nx * ny), nx, ny)
        dr.backward(reg)
        with dr.suspend_grad():
            z_now = DEPTH + np.asarray(smoothed(opt["u"], taps, nx * ny)).reshape(nx, ny)
        history.append((total + float(reg[0]), rms(z_now)))
        if callback is not None:
            callback(it, history[-1])
        opt.step()
        opt.set_learning_rate(lr * decay ** (it + 1))
    seconds = time.perf_counter() - t0
    with dr.suspend_grad():
        z_fin = DEPTH + np.asarray(smoothed(opt["u"], taps, nx * ny)).reshape(nx, ny)
    return {"history": history, "rms_start": rms(np.full_like(z_true, DEPTH)), "rms_final": rms(z_fin),
            "heights": (z_true, z_fin), "x": x, "y": y, "seen": seen, "seconds": seconds, "iterations": iterations,
            "pings": len(poses)}


def figure(result, path):
    plt = pyplot()
    z_true, z_fin = result["heights"]
    ext = [result["y"][0], result["y"][-1], result["x"][0], result["x"][-1]]
    fig, ax = plt.subplots(1, 4, figsize=(13, 3.2))
    lo, hi = float(min(z_true.min(), z_fin.min())), float(max(z_true.max(), z_fin.max()))
    for a, z, title in ((ax[0], z_true, "true heights"), (ax[1], np.full_like(z_true, DEPTH), "start (flat)"),
                        (ax[2], z_fin, "recovered")):
        im = a.imshow(z, origin="lower", extent=ext, vmin=lo, vmax=hi, aspect="auto")
        a.set_title(title)
        a.set_xlabel("y across track (m)")
    ax[0].set_ylabel("x along track (m)")
    fig.colorbar(im, ax=ax[2], label="z (m)")
    h = np.asarray(result["history"])
    ax[3].plot(100 * h[:, 1])
    ax[3].set_xlabel("iteration")
    ax[3].set_ylabel("RMS height error (cm), seen cells")
    save_figure(fig, path)


def main(argv=None):
    a = argument_parser(__doc__, "recover_seabed.png", iterations=60, seed=3, target_seed=False).parse_args(argv)

    def show(it, h):
        print(f"iter {it:3d}  loss {h[0]:.3e}  RMS height error {100 * h[1]:5.2f} cm")

    res = recover(iterations=a.iterations, spp=a.spp, seed=a.seed, callback=show)
    print(f"RMS height error over the seen cells: {100 * res['rms_start']:.2f} cm (flat start) -> "
          f"{100 * res['rms_final']:.2f} cm after {res['iterations']} iterations over {res['pings']} pings, "
          f"{res['seconds']:.1f} s")
    figure(res, a.out)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
