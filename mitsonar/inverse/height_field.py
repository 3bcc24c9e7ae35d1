"""Analysis by synthesis: a height field refined until rendering it gives back the recorded scans.

A seabed surface ``z(x, y)`` on a regular grid (a mesh with one normal a facet) is rendered with the
survey's poses by the differentiable renderer (``mi.render(scene, params)``; the derivative with
respect to ``<mesh>.vertex_positions`` follows the echoes' ranges and incidence angles,
``plugins/integrators/paths/path_replay.py``), compared with the recorded intensities, and its heights are moved by
Adam (``mi.ad.Adam``) down the loss

    L(z) = sum_pings  sum (B s_k(z) - B t_k)^2 / sum (B t_k)^2  +  lambda sum (laplacian z)^2

with ``B`` a Gaussian blur along range (``blur`` bins: a range error of a few bins changes the loss
smoothly; it is narrowed stage by stage) and the Laplacian over the grid's interior vertices (it
fills what no ping sees: the nadir gap, the grid's border).

Multi-resolution: the heights are ``z = z0 + sum_l S_l u_l`` with ``S_l`` a Gaussian blur of
``sigmas[l]`` vertices; stage ``l`` of the schedule adds ``u_l`` (coarse first: the broad shape,
whose ranges are far off at the start, then the detail), each stage with its own range blur.

Limits (stated, not worked around): silhouettes and facet edges are not differentiated (a facet's
normal jumps at its edges; moving vertices moves those jumps across the beam, a bias measured by
``benchmarks/inverse.py``); the echoes are single-bounce (``max_depth`` 1). A height field cannot
hold walls or piles: vertical structure needs a mesh whose silhouettes the derivative follows.

Seeds: every render of a fit takes ``seed + k`` for ping ``k`` (the same in each iteration: common
random numbers), so a fit is deterministic per seed.
"""
from __future__ import annotations

import math
import time

import numpy as np

from mitsonar.inverse.driver import check_poses_and_targets, jit_poses_targets, one_thread_if, render_loss

__all__ = ["grid_mesh", "refine_height_field", "render_loss", "sidescan_xml"]


def grid_mesh(x, y, z):
    """(vertices (nx ny, 3) float32, faces (m, 3) uint32) of the height field ``z[i, j]`` at
    ``(x[i], y[j])``, two triangles a cell, counter-clockwise seen from above (normals up)."""
    x, y, z = np.asarray(x, np.float64), np.asarray(y, np.float64), np.asarray(z, np.float64)
    nx, ny = len(x), len(y)
    if z.shape != (nx, ny):
        raise ValueError(f"grid_mesh: z must have shape (len(x), len(y)) = ({nx}, {ny}), not {z.shape}")
    X, Y = np.meshgrid(x, y, indexing="ij")
    V = np.stack([X.ravel(), Y.ravel(), z.ravel()], 1).astype(np.float32)
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]).astype(np.uint32)
    return V, F


def sidescan_xml(ply, *, n_bins=200, range_max=10.0, depression=30.0, beamwidth_h=2.0, beamwidth_v=50.0,
                 bsdf='<string name="preset" value="seabed_rock"/>'):
    """A scene of a two-channel side-scan head (``id="head"``, one ping) over the mesh ``ply``
    (``id="seabed"``, face normals), single-bounce echoes."""
    from mitsonar.kinds import SIDESCAN

    return ('<scene version="3.0.0"><integrator type="sonar_tof"><integer name="max_depth" value="1"/></integrator>'
            f'<sensor type="sonar" id="head"><string name="kind" value="{SIDESCAN.name}"/><string name="side" value="both"/>'
            f'<integer name="n_pings" value="1"/><float name="depression" value="{depression}"/>'
            f'<float name="range_min" value="0"/><float name="range_max" value="{range_max}"/>'
            f'<integer name="n_bins" value="{n_bins}"/><float name="beamwidth_h" value="{beamwidth_h}"/>'
            f'<float name="beamwidth_v" value="{beamwidth_v}"/></sensor>'
            f'<bsdf type="acoustic" id="bed">{bsdf}</bsdf>'
            f'<shape type="ply" id="seabed"><string name="filename" value="{ply}"/>'
            '<boolean name="face_normals" value="true"/><ref id="bed"/></shape></scene>')


def smoothing_taps(nx, ny, sigma):
    """(rows, cols, weights) of a normalised Gaussian blur of ``sigma`` vertices (to 2 sigma)."""
    half = max(1, int(math.ceil(2 * sigma)))
    off = np.arange(-half, half + 1)
    rows, cols, w = [], [], []
    I, J = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    I, J = I.ravel(), J.ravel()
    for a in off:
        for b in off:
            ok = (I + a >= 0) & (I + a < nx) & (J + b >= 0) & (J + b < ny)
            rows.append((I * ny + J)[ok])
            cols.append(((I + a) * ny + J + b)[ok])
            w.append(np.full(ok.sum(), math.exp(-0.5 * (a * a + b * b) / sigma ** 2)))
    rows, cols, w = np.concatenate(rows), np.concatenate(cols), np.concatenate(w)
    w = w / np.bincount(rows, weights=w, minlength=nx * ny)[rows]
    return rows.astype(np.uint32), cols.astype(np.uint32), w.astype(np.float32)


def smoothed(u, taps, n):
    """``S u`` (Dr.Jit, differentiable) for ``taps`` from `smoothing_taps`."""
    import drjit as dr
    import mitsuba as mi

    rows, cols, w = taps
    out = dr.zeros(mi.Float, n)
    dr.scatter_add(out, dr.gather(mi.Float, u, mi.UInt32(cols)) * mi.Float(w), mi.UInt32(rows))
    return out


def laplacian_penalty(z, nx, ny):
    """``sum (laplacian z)^2`` over the interior vertices of the ``nx x ny`` grid (Dr.Jit, differentiable)."""
    import drjit as dr
    import mitsuba as mi

    i, j = np.meshgrid(np.arange(1, nx - 1), np.arange(1, ny - 1), indexing="ij")
    c = (i * ny + j).ravel()
    g = lambda k: dr.gather(mi.Float, z, mi.UInt32(k.astype(np.uint32)))  # noqa: E731
    lap = g(c - ny) + g(c + ny) + g(c - 1) + g(c + 1) - 4.0 * g(c)
    return dr.sum(dr.square(lap))


def refine_height_field(scene, x, y, z_start, poses, targets, *, stages=((2.5, 6.0, 20), (1.0, 2.0, 20)),
                        spp=256, seed=0, lr=0.05, lr_decay=1.0, smooth=0.05, head="head", mesh="seabed",
                        deterministic=True, callback=None):
    """Refine the heights of the grid mesh ``mesh`` of ``scene`` so that its renders match ``targets``.

    Parameters
    ----------
    scene : mitsuba.Scene
        A scene with a sonar sensor ``head`` and the grid mesh ``mesh`` (`grid_mesh` of ``x``,
        ``y``; face normals), e.g. from `sidescan_xml`.
    x, y : array_like
        The grid's vertex coordinates (m), ``nx`` and ``ny`` of them.
    z_start : array_like (nx, ny)
        The heights to start from (m).
    poses : sequence of (4, 4) arrays
        The head's ``to_world`` for each recorded ping.
    targets : sequence of arrays
        The recorded intensities of each ping, the renders' shape ``(n_rows, n_bins)``.
    stages : sequence of (sigma_vertices, blur_bins, iterations)
        The multi-resolution schedule: each stage adds a height component smoothed by
        ``sigma_vertices`` and compares the scans blurred by ``blur_bins`` along range.
    spp, seed : int
        Samples per ping; ping ``k`` renders with ``seed + k`` in every iteration.
    lr : float
        Adam's step (m of the smoothed component per iteration, about).
    lr_decay : float
        Each stage's step falls geometrically from ``lr`` to ``lr * lr_decay`` over its iterations.
    smooth : float
        ``lambda`` of the Laplacian penalty (0: none).
    deterministic : bool
        Run Dr.Jit on one thread during the fit (restored after): the vertex gradients and the
        smoothing are sums by atomic adds, whose order, and so whose rounding, varies between
        runs on several threads; on one the same seed gives the same heights, bit for bit.
    callback : callable, optional
        ``callback(iteration, loss, z)`` after each iteration.

    Returns
    -------
    dict
        ``z`` (nx, ny) refined heights, ``loss`` per iteration (the render-and-compare part, at
        the stage's blur), ``loss_start`` and ``loss_final`` (both at the last stage's blur),
        ``loss_by_blur`` (each stage's blur: (start, final)), ``seconds``.
    """
    with one_thread_if(deterministic):
        return _refine(scene, x, y, z_start, poses, targets, stages, spp, seed, lr, lr_decay, smooth, head, mesh,
                       callback)


def _refine(scene, x, y, z_start, poses, targets, stages, spp, seed, lr, lr_decay, smooth, head, mesh, callback):
    import drjit as dr
    import mitsuba as mi

    from mitsonar.sim.render import scan_parameters

    x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
    nx, ny = len(x), len(y)
    z0 = np.asarray(z_start, np.float64)
    if z0.shape != (nx, ny):
        raise ValueError(f"refine_height_field: z_start must have shape ({nx}, {ny}), not {z0.shape}")
    check_poses_and_targets("refine_height_field", poses, targets, scene, head)
    if not stages:
        raise ValueError("refine_height_field: stages must hold at least one (sigma, blur, iterations)")
    key = f"{mesh}.vertex_positions"
    params = scan_parameters(scene, [f"{head}.to_world", key])
    V0, _ = grid_mesh(x, y, z0)
    n = nx * ny
    xy = mi.Float(np.where(np.arange(V0.size) % 3 == 2, 0.0, V0.ravel()).astype(np.float32))
    zsel = mi.Float((np.arange(V0.size) % 3 == 2).astype(np.float32))
    vid = dr.arange(mi.UInt32, V0.size) // 3
    z0_dr = mi.Float(z0.ravel().astype(np.float32))
    tf, tg = jit_poses_targets(poses, targets)

    taps = [smoothing_taps(nx, ny, float(s)) for s, _, _ in stages]
    opt = mi.ad.Adam(lr=lr)

    def heights(k_active):
        z = z0_dr
        for l in range(k_active):
            z = z + smoothed(opt[f"u{l}"], taps[l], n)
        return z

    def data_loss(z, blur, grad):
        """The summed loss of every ping (`render_loss`); ``z``: the heights, or a function making
        them anew per ping."""
        def vertices():
            return xy + zsel * dr.gather(mi.Float, z() if callable(z) else z, vid)

        return render_loss(scene, params, head, key, tf, tg, vertices, blur=blur, grad=grad, spp=spp, seed=seed)

    t0 = time.perf_counter()
    blurs = sorted({float(b) for _, b, _ in stages})
    last_blur = float(stages[-1][1])
    with dr.suspend_grad():
        start = {b: data_loss(z0_dr, b, False) for b in blurs}
    history = []
    it = 0
    for s, (_, blur, iters) in enumerate(stages):
        opt[f"u{s}"] = dr.zeros(mi.Float, n)
        for j in range(int(iters)):
            opt.set_learning_rate(lr * float(lr_decay) ** (j / max(int(iters) - 1, 1)))
            total = data_loss(lambda: heights(s + 1), float(blur), True)
            if smooth:      # smooth 0: no penalty (its graph would hold no gradient for backward)
                dr.backward(smooth * laplacian_penalty(heights(s + 1), nx, ny))
            history.append(total)
            opt.step()
            if callback is not None:
                with dr.suspend_grad():
                    callback(it, total, np.asarray(heights(s + 1)).reshape(nx, ny))
            it += 1
    with dr.suspend_grad():
        z_fin = heights(len(stages))
        final = {b: data_loss(z_fin, b, False) for b in blurs}
        z_fin = np.asarray(z_fin, np.float64).reshape(nx, ny)
    params[key] = mi.Float(V0.ravel())
    params.update()
    return {"z": z_fin, "loss": history, "loss_start": start[last_blur], "loss_final": final[last_blur],
            "loss_by_blur": {b: (start[b], final[b]) for b in blurs}, "seconds": time.perf_counter() - t0}
