"""What every inverse problem of `mitsonar.inverse` shares: the checks of its inputs, the
render-and-compare loss (`render_loss`) and the one staged-Adam driver (`staged_refine`: check, then
refine stage by stage, then put the scene back) that `mitsonar.inverse.room.refine_room` and
`mitsonar.inverse.piles.refine_piles` run their models through.

A model is what differs between those problems: its unknowns (Adam's variables), how they make
the mesh vertices, what is kept after each step, and the result. `staged_refine` asks it through
one function, ``build(params, opt)``, called once the scene's parameters are traversed and Adam
made, which puts its unknowns in ``opt`` and returns ``(vertices, step_done, finish)``:
``vertices()`` the mesh vertex arrays from ``opt`` (called per ping, see `render_loss`),
``step_done(iteration, loss)`` after each Adam step (or None), ``finish()`` the model's part of the
result (read from ``opt``), with the scene's meshes set back to their start (``params`` updated
after it).
"""
from __future__ import annotations

import contextlib
import math
import time

import numpy as np

__all__ = ["check_adam_stages", "check_poses_and_targets", "jit_poses_targets", "one_thread_if", "render_loss",
           "staged_adam", "staged_refine", "write_ply"]


def check_poses_and_targets(what, poses, targets, scene=None, head=None):
    """One-line ``ValueError`` (``what: ...``) unless there is one 4x4 pose per target and every
    target is a 2-D (rows, bins) array, of the shape the sensor ``head`` of ``scene`` renders when
    they are given; checked before anything renders (a Dr.Jit size error would come after the
    first render)."""
    if len(poses) != len(targets) or not len(poses):
        raise ValueError(f"{what}: one target per pose is needed, got {len(poses)} poses and {len(targets)} targets")
    shape = None
    if scene is not None:
        shape = next((tuple(int(v) for v in s.film().size())[::-1] for s in scene.sensors() if s.id() == head), None)
    for k, (P, t) in enumerate(zip(poses, targets)):
        if np.shape(P) != (4, 4):
            raise ValueError(f"{what}: poses[{k}] must be a 4x4 matrix, not shape {np.shape(P)}")
        if np.ndim(t) != 2:
            raise ValueError(f"{what}: targets[{k}] must be a (rows, bins) array like the renders, not shape "
                             f"{np.shape(t)}")
        if shape is not None and tuple(np.shape(t)) != shape:
            raise ValueError(f"{what}: targets[{k}] has shape {tuple(np.shape(t))}, the head {head!r} renders "
                             f"{shape} (rows, bins)")


def check_adam_stages(what, lr, lr_decay, stages):
    """One-line ``ValueError`` (``what: ...``) unless ``lr > 0``, ``0 < lr_decay <= 1`` and
    ``stages`` are ``(blur_bins >= 0, iterations >= 0)`` pairs: the settings `staged_refine`
    checks."""
    if not (lr > 0 and 0 < lr_decay <= 1):
        raise ValueError(f"{what}: need lr > 0 and 0 < lr_decay <= 1 (got lr {lr!r}, lr_decay {lr_decay!r})")
    if not stages or any(len(s) != 2 or not s[0] >= 0 or int(s[1]) < 0 for s in stages):
        raise ValueError(f"{what}: stages must be (blur_bins >= 0, iterations >= 0) pairs, not {stages!r}")


@contextlib.contextmanager
def one_thread_if(deterministic):
    """Dr.Jit on one thread for the block when ``deterministic`` (its thread count restored after):
    the vertex gradients are sums by atomic adds, whose order and rounding vary on several."""
    import drjit as dr

    threads = dr.thread_count()
    if deterministic:
        dr.set_thread_count(1)
    try:
        yield
    finally:
        dr.set_thread_count(threads)


def jit_poses_targets(poses, targets):
    """The pings' head transforms (``mi.Transform4f``) and targets (``mi.TensorXf`` (rows, bins, 1)),
    converted once for `render_loss`."""
    import mitsuba as mi

    tf = [mi.Transform4f(mi.Matrix4f(np.asarray(P, np.float64))) for P in poses]
    tg = [mi.TensorXf(np.asarray(t, np.float32).reshape(np.shape(t)[0], np.shape(t)[1], 1)) for t in targets]
    return tf, tg


def _blur_range(img, sigma_bins):
    """``img`` (n_rows, n_bins[, 1]) blurred along range by a Gaussian of ``sigma_bins`` bins."""
    import drjit as dr
    import mitsuba as mi

    n_rows, n_bins = img.shape[0], img.shape[1]
    flat = img.array if hasattr(img, "array") else img
    if sigma_bins <= 0:
        return flat
    half = max(1, int(math.ceil(3 * sigma_bins)))
    w = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma_bins) ** 2)
    w /= w.sum()
    idx = dr.arange(mi.UInt32, n_rows * n_bins)
    b = mi.Int32(idx % n_bins)
    out = dr.zeros(mi.Float, n_rows * n_bins)
    for j, wj in zip(range(-half, half + 1), w):
        ok = (b + j >= 0) & (b + j < n_bins)
        out += float(wj) * dr.gather(mi.Float, flat, mi.UInt32(mi.Int32(idx) + j), ok)
    return out


def render_loss(scene, params, head, key, transforms, targets, vertices, *, blur, grad, spp, seed, floor_db=None,
                across_beams=False):
    """The summed render-and-compare loss of every ping, ``sum_k |B s_k - B t_k|^2 / |B t_k|^2``
    (`_blur_range` ``B``), the mesh ``key``'s vertex positions set to ``vertices()`` and the head
    ``head`` moved to ``transforms[k]`` for ping ``k`` (rendered with ``seed + k``; ``key`` may be a
    tuple of meshes' keys, ``vertices()`` then giving one array each); with ``grad``
    each ping's loss is back-propagated at once. ``vertices`` is called per ping: each backward
    pass frees the graph it traversed, so the vertices are made anew for the next ping (else only
    the first ping's gradient would reach the unknowns). Shared by `refine_height_field` and
    `mitsonar.inverse.room` and `mitsonar.inverse.piles`.

    With ``floor_db`` (dB, negative) the loss compares levels instead: the mean over pings of
    ``mean_bins (10 log10(B s_k + e) - 10 log10(B t_k + e))^2`` (dB^2), ``e`` the floor ``floor_db``
    below the peak of all the pings' compared targets (``max_k max B t_k``, or of their beam
    averages with ``across_beams``; a silent ping has the same floor as the others). The relative
    loss is ruled by the brightest echoes (a pile's face holds most of a harbour frame's energy); in
    dB a faint echo, a mud seabed's at grazing incidence, counts as much as a bright one, and bins
    where one side is silent count by how far the other rises above the floor. ``across_beams``:
    each ping's intensities are first averaged over its rows (beams), the ping's mean level against
    range: the seabed's echo, in every beam, then sets the level, one beam's pile hardly does, and
    the average of 100 beams has a tenth of one beam's Monte Carlo noise, which the logarithm would
    otherwise turn into a bias (the mean of the log of a noisy estimate is below the log of its
    mean; a median over the beams, blind to the piles, was biased the same way: 0.4 m too high a
    seabed on the harbour survey, 0.25 m on the tests' pile)."""
    import drjit as dr
    import mitsuba as mi

    def over_beams(flat, n_rows, n_bins):  # rows summed in a fixed order: the same bits every run
        j = dr.arange(mi.UInt32, n_bins)
        out = dr.gather(mi.Float, flat, j)
        for r in range(1, n_rows):
            out += dr.gather(mi.Float, flat, j + r * n_bins)
        return out / n_rows

    def compared(x):  # what is compared of a ping: blurred along range, averaged over its beams
        flat = _blur_range(x, blur)
        return over_beams(flat, *x.shape[:2]) if across_beams else flat

    total = 0.0
    wanted = [compared(t) for t in targets]
    if floor_db is not None:
        peak = max(float(dr.max(b)[0]) for b in wanted)
        if not (math.isfinite(float(floor_db)) and floor_db < 0 and peak > 0):
            raise ValueError(f"render_loss: floor_db must be a negative number of dB and some target above zero "
                             f"(got floor_db={floor_db!r}, peak {peak!r})")
        e = peak * 10.0 ** (float(floor_db) / 10.0)
    for k, (P, b) in enumerate(zip(transforms, wanted)):
        params[f"{head}.to_world"] = P
        if isinstance(key, str):
            params[key] = vertices()
        else:  # several meshes: ``vertices()`` gives one array per key
            for k_, v_ in zip(key, vertices()):
                params[k_] = v_
        params.update()
        if grad:
            img = mi.render(scene, params, spp=spp, seed=seed + k)
        else:
            with dr.suspend_grad():
                img = mi.render(scene, params, spp=spp, seed=seed + k)
        a = compared(img)
        if floor_db is None:
            loss = dr.sum(dr.square(a - b)) / dr.sum(dr.square(b))
        else:
            db = (10.0 / math.log(10.0)) * (dr.log(a + e) - dr.log(b + e))
            loss = dr.mean(dr.square(db)) / len(targets)
        if grad:
            dr.backward(loss)
        total += float(loss[0])
    return total


def staged_adam(opt, stages, lr, lr_decay, data_loss, after_step=None):
    """Adam's steps over ``stages`` of ``(blur_bins, iterations)``, the loop of
    `staged_refine`: each step back-propagates ``data_loss(blur, True)`` (the summed loss of every
    ping) and moves ``opt``, its rate falling geometrically from ``lr`` to ``lr * lr_decay`` over
    each stage; ``after_step(iteration, loss)`` after each. Returns ``(loss at the last stage's
    blur before, the losses per iteration, the loss at the last stage's blur after)``."""
    import drjit as dr

    last_blur = float(stages[-1][0])
    with dr.suspend_grad():
        start = data_loss(last_blur, False)
    history = []
    for blur, iters in stages:
        for j in range(int(iters)):
            opt.set_learning_rate(lr * float(lr_decay) ** (j / max(int(iters) - 1, 1)))
            history.append(data_loss(float(blur), True))
            opt.step()
            if after_step is not None:
                after_step(len(history) - 1, history[-1])
    with dr.suspend_grad():
        final = data_loss(last_blur, False)
    return start, history, final


def write_ply(path, V, F):
    """Write a mesh without vertex normals (a facet's normal is its own) as binary PLY."""
    import mitsuba as mi

    m = mi.Mesh("seabed", len(V), len(F), has_vertex_normals=False)
    p = mi.traverse(m)
    p["vertex_positions"] = mi.Float(np.asarray(V, np.float32).ravel())
    p["faces"] = mi.UInt32(np.asarray(F, np.uint32).ravel())
    p.update()
    m.write_ply(path)


def staged_refine(what, scene, poses, targets, build, *, head, key, stages, spp, seed, lr, lr_decay,
                  deterministic):
    """The check-then-refine driver of `refine_room` and `refine_piles`: refuse bad ``poses``,
    ``targets`` (`check_poses_and_targets`), ``lr``, ``lr_decay`` and ``stages``
    (`check_adam_stages`) in one line naming ``what`` before anything renders; then, on one Dr.Jit
    thread when ``deterministic`` (`one_thread_if`), traverse ``scene``'s head ``head`` and mesh
    ``key`` (a key, or a tuple of keys), make Adam (``lr``), let the model ``build(params, opt)``
    (the module docstring) put its unknowns in it, step them through ``stages`` (`staged_adam`, the
    loss `render_loss` of every ping at ``spp`` and ``seed + k``), and return the model's
    ``finish()`` with ``loss`` (per iteration), ``loss_start``, ``loss_final`` (at the last stage's
    blur) and ``seconds``."""
    check_poses_and_targets(what, poses, targets, scene, head)
    check_adam_stages(what, lr, lr_decay, stages)
    with one_thread_if(deterministic):
        import mitsuba as mi

        from mitsonar.sim.render import scan_parameters

        keys = [key] if isinstance(key, str) else list(key)
        params = scan_parameters(scene, [f"{head}.to_world", *keys])
        tf, tg = jit_poses_targets(poses, targets)
        opt = mi.ad.Adam(lr=lr)
        vertices, step_done, finish = build(params, opt)

        def data_loss(blur, grad):
            return render_loss(scene, params, head, key, tf, tg, vertices, blur=blur, grad=grad, spp=spp, seed=seed)

        t0 = time.perf_counter()
        start, history, final = staged_adam(opt, stages, lr, lr_decay, data_loss, step_done)
        out = finish()
        params.update()
        return {**out, "loss": history, "loss_start": start, "loss_final": final, "seconds": time.perf_counter() - t0}
