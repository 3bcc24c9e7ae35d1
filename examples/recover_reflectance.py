"""Recover the reflectance of a scene's materials from its scans (issue "Inverse problems").

The tank of ``_inverse.tank_xml`` has two acoustic materials, ``wall`` (concrete-like: weak diffuse,
strong narrow specular lobe) and ``floor`` (a seabed: mostly diffuse, a broad lobe). A mechanical
head profiles it in a vertical plane (scan axis horizontal), so both materials are seen at normal
incidence (the floor straight below, the end walls straight ahead and behind), where the specular
lobe shows, and obliquely, where the diffuse term does: all six of ``diffuse``, ``specular``,
``shininess`` are observable. Starting from wrong values, Adam (``mi.ad.Adam``) fits them to the
target scan through the derivative of ``mi.render`` with respect to the BSDF parameters (path
replay, ``plugins/integrators/paths/path_replay.py``).

Parametrisation: each value is ``start * exp(u)``, ``u`` fitted (relative steps, positive values);
``diffuse + specular`` is kept <= 0.99 (energy conservation) by scaling both down after a step that
crosses it. Loss: L2 between the logarithms of the range-blurred scans (their misfit in dB, so
that the weak oblique echoes count as much as the strong normal ones). The target is rendered with the
seed the fit uses (common random numbers), so the loss is 0 at the truth; ``--target-seed``
renders it with other paths (the optimum then moves by the scans' Monte Carlo noise).

Run: ``python examples/recover_reflectance.py --out recover_reflectance.png``: prints the values per
iteration and writes a figure of the loss and of each parameter's relative error per iteration.
"""
from __future__ import annotations

import math
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _inverse import argument_parser, log_l2, loss_figure, positive_int, save_figure, tank_xml  # noqa: E402

TRUTH = {"wall": (0.15, 0.6, 30.0), "floor": (0.4, 0.2, 8.0)}
START = {"wall": (0.3, 0.35, 12.0), "floor": (0.25, 0.35, 16.0)}
NAMES = ("diffuse", "specular", "shininess")


def profiler_mount():
    """A head profiling the tank's x-z plane from (0.5, -0.3, -1.5): scan axis (beam +y) along world
    +y, boresight at bearing 0 along world +x; the sweep passes the floor 1.5 m below at normal
    incidence and the end walls x = +-5 at normal incidence."""
    return np.array([[0.0, 0.0, 1.0, 0.5],
                     [0.0, 1.0, 0.0, -0.3],
                     [-1.0, 0.0, 0.0, -1.5],
                     [0.0, 0.0, 0.0, 1.0]])


def _keys():
    return [f"{m}.{n}" for m in ("wall", "floor") for n in NAMES]


def _set(params, values):
    for m in ("wall", "floor"):
        d, s = values[f"{m}.diffuse"], values[f"{m}.specular"]
        total = d + s
        scale = 0.99 / total if total > 0.99 else 1.0
        params[f"{m}.diffuse"] = mi_float(d * scale)
        params[f"{m}.specular"] = mi_float(s * scale)
        params[f"{m}.shininess"] = mi_float(values[f"{m}.shininess"])


def mi_float(v):
    import mitsuba as mi

    return mi.Float(v) if not hasattr(v, "__len__") else v


def recover(iterations=100, spp=1024, seed=5, n_pings=36, n_bins=160, blur=1.0, lr=0.08, truth=TRUTH,
            start=START, target_seed=None, callback=None):
    """Fit the six reflectance parameters; returns a dict with ``history`` (per iteration: loss and
    the values, in the order of ``keys``), ``keys``, ``values`` (final), ``relative_errors``,
    ``seconds`` and ``iterations``. ``lr``: Adam's step in ``u`` (about a relative change per step),
    decayed geometrically to a 10th over the iterations. ``target_seed``: render the target with
    other paths than the fit (default: the fit's seed)."""
    import drjit as dr
    import mitsuba as mi

    import mitsonar
    from mitsonar.sim.render import scan_parameters

    iterations = positive_int("iterations", iterations, 1, 100000)
    spp = positive_int("spp", spp, 1, 1 << 24)
    for name, table in (("truth", truth), ("start", start)):
        for m, vals in table.items():
            if m not in ("wall", "floor") or len(vals) != 3 or min(vals) <= 0 or vals[0] + vals[1] > 1:
                raise SystemExit(f"{name}[{m!r}]: {vals!r} is not allowed (materials 'wall', 'floor'; "
                                 f"(diffuse, specular, shininess), all > 0, diffuse + specular <= 1)")
    scene = mitsonar.load_scene(tank_xml(profiler_mount(), n_pings=n_pings, n_bins=n_bins,
                                         walls=truth["wall"], floor=truth["floor"]))
    keys = _keys()
    params = scan_parameters(scene, keys)
    true_vals = {f"{m}.{n}": truth[m][i] for m in truth for i, n in enumerate(NAMES)}
    target = mi.render(scene, spp=spp, seed=seed if target_seed is None else target_seed)
    dr.eval(target)
    start_vals = {f"{m}.{n}": start[m][i] for m in start for i, n in enumerate(NAMES)}

    opt = mi.ad.Adam(lr=lr)
    for k in keys:
        opt[k] = mi.Float(0.0)
    decay = 0.1 ** (1.0 / max(1, iterations - 1))
    history = []
    t0 = time.perf_counter()
    for it in range(iterations):
        vals = {k: start_vals[k] * dr.exp(opt[k]) for k in keys}
        _set(params, vals)
        params.update()
        img = mi.render(scene, params, spp=spp, seed=seed)
        loss = log_l2(img, target, blur)
        dr.backward(loss)
        now = [float(params[k][0]) for k in keys]
        history.append([float(loss[0])] + now)
        if callback is not None:
            callback(it, history[-1], keys)
        opt.step()
        opt.set_learning_rate(lr * decay ** (it + 1))
    seconds = time.perf_counter() - t0
    with dr.suspend_grad():
        final = {k: float((start_vals[k] * dr.exp(opt[k]))[0]) for k in keys}
        _set(params, {k: mi.Float(v) for k, v in final.items()})
        final = {k: float(params[k][0]) for k in keys}
    rel = {k: abs(final[k] - true_vals[k]) / true_vals[k] for k in keys}
    return {"history": history, "keys": keys, "values": final, "truth": true_vals, "relative_errors": rel,
            "seconds": seconds, "iterations": iterations}


def figure(result, path):
    fig, right, h, it = loss_figure(result["history"], "L2 loss of log intensity")
    for j, k in enumerate(result["keys"]):
        t = result["truth"][k]
        right.semilogy(it, np.abs(h[:, 1 + j] - t) / t, label=k)
    right.axhline(0.05, color="0.6", lw=0.8, ls="--")
    right.set_xlabel("iteration")
    right.set_ylabel("relative error")
    right.legend(fontsize=7)
    fig.suptitle("Reflectance recovered from scans of a tank")
    save_figure(fig, path)


def main(argv=None):
    a = argument_parser(__doc__, "recover_reflectance.png", iterations=100, seed=5).parse_args(argv)

    def show(it, h, keys):
        print(f"iter {it:3d}  loss {h[0]:.3e}  " + "  ".join(f"{k} {v:.3f}" for k, v in zip(keys, h[1:])))

    res = recover(iterations=a.iterations, spp=a.spp, seed=a.seed, target_seed=a.target_seed, callback=show)
    worst = max(res["relative_errors"].values())
    print("final: " + ", ".join(f"{k} {res['values'][k]:.4f} (true {res['truth'][k]:g})" for k in res["keys"]))
    print(f"largest relative error {100 * worst:.2f} % after {res['iterations']} iterations, {res['seconds']:.1f} s")
    figure(res, a.out)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
