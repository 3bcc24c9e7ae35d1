"""What the inverse-problem examples share: a range-blurred L2 loss on scans, a small-pose
parametrisation, argument checks and the figure writer.

The examples (``calibrate_mount.py``, ``recover_reflectance.py``, ``recover_seabed.py``) fit scene
parameters to target scans with ``mi.render(scene, params, spp=, seed=)`` (issue "Differentiable
scans") and Mitsuba's optimiser ``mi.ad.Adam``.
"""
from __future__ import annotations

import argparse
import math
import os

import numpy as np


def blur_weights(sigma_bins: float):
    """Normalised Gaussian taps (offset, weight) of standard deviation ``sigma_bins`` bins, to 3 sigma."""
    if sigma_bins <= 0:
        return [(0, 1.0)]
    half = max(1, int(math.ceil(3 * sigma_bins)))
    w = [math.exp(-0.5 * (j / sigma_bins) ** 2) for j in range(-half, half + 1)]
    s = sum(w)
    return [(j, wj / s) for j, wj in zip(range(-half, half + 1), w)]


def blur_range(img, sigma_bins: float):
    """``img`` (``mi.TensorXf`` (n_rows, n_bins, 1)) convolved along range with a Gaussian of
    ``sigma_bins`` bins (zero outside the window): a Dr.Jit expression, differentiable.

    A pulse of finite length spreads every echo over neighbouring bins in the same way; comparing
    scans through it turns a sub-bin range error into a smooth change of the loss."""
    import drjit as dr
    import mitsuba as mi

    n_rows, n_bins = img.shape[0], img.shape[1]
    flat = img.array
    idx = dr.arange(mi.UInt32, n_rows * n_bins)
    b = mi.Int32(idx % n_bins)
    out = dr.zeros(mi.Float, n_rows * n_bins)
    for j, w in blur_weights(sigma_bins):
        src = b + j
        ok = (src >= 0) & (src < n_bins)
        out += w * dr.gather(mi.Float, flat, mi.UInt32(mi.Int32(idx) + j), ok)
    return out


def relative_l2(img, target, sigma_bins: float):
    """``sum (blur(img) - blur(target))^2 / sum blur(target)^2``: the loss every example minimises
    (intensities are ~1e-6 in absolute units, so the loss is made relative)."""
    import drjit as dr

    a, t = blur_range(img, sigma_bins), blur_range(target, sigma_bins)
    return dr.sum(dr.square(a - t)) / dr.sum(dr.square(t))


def log_l2(img, target, sigma_bins: float, floor: float = 1e-4):
    """``mean (log(blur(img) + e) - log(blur(target) + e))^2``, ``e = floor * max(blur(target))``: the
    misfit of the scans in decibels (as a sonar display shows them), so that weak oblique echoes
    weigh as much as the strong ones near normal incidence."""
    import drjit as dr

    a, t = blur_range(img, sigma_bins), blur_range(target, sigma_bins)
    e = floor * dr.max(dr.detach(t))
    return dr.mean(dr.square(dr.log(a + e) - dr.log(t + e)))


def small_pose(t, r):
    """``mi.Transform4f`` of a translation ``t`` (m) after a rotation by the rotation vector ``r``
    (radians; Rodrigues' formula ``R = I + sin(a)/a K + (1 - cos a)/a^2 K^2``, ``a = |r|``, ``K`` the
    cross-product matrix of ``r``): differentiable in ``t`` and ``r``, also at ``r = 0``."""
    import drjit as dr
    import mitsuba as mi

    a2 = dr.squared_norm(r) + 1e-20
    a = dr.sqrt(a2)
    s = dr.sin(a) / a
    c = dr.select(a2 > 1e-8, (1.0 - dr.cos(a)) / a2, 0.5)
    K = mi.Matrix3f(0.0, -r.z, r.y,
                    r.z, 0.0, -r.x,
                    -r.y, r.x, 0.0)
    R = mi.Matrix3f(1.0) + s * K + c * (K @ K)
    m = mi.Matrix4f(R[0, 0], R[0, 1], R[0, 2], t.x,
                    R[1, 0], R[1, 1], R[1, 2], t.y,
                    R[2, 0], R[2, 1], R[2, 2], t.z,
                    0.0, 0.0, 0.0, 1.0)
    return mi.Transform4f(m)


def rotation_angle_deg(R) -> float:
    """The angle (degrees) of the rotation matrix ``R`` (3 x 3, NumPy)."""
    import numpy as np

    c = (float(np.trace(R)) - 1.0) / 2.0
    return math.degrees(math.acos(max(-1.0, min(1.0, c))))


def positive_int(name: str, value, lo: int = 1, hi: int = 1 << 20) -> int:
    """``value`` as an int in [lo, hi], else SystemExit with one line naming ``name``."""
    try:
        v = int(value)
        ok = v == value and lo <= v <= hi
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise SystemExit(f"{name}: {value!r} is not allowed (a whole number from {lo} to {hi})")
    return v


def argument_parser(doc: str, out: str, iterations: int, seed: int, target_seed: bool = True):
    """The examples' command line: ``--iterations``, ``--spp``, ``--seed``, ``--target-seed`` (with
    ``target_seed``) and ``--out`` (the figure), with the example's defaults; the description is the
    first line of ``doc``."""
    ap = argparse.ArgumentParser(description=doc.split("\n")[0])
    ap.add_argument("--iterations", type=int, default=iterations)
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--seed", type=int, default=seed)
    if target_seed:
        ap.add_argument("--target-seed", type=int, default=None)
    ap.add_argument("--out", default=out, help="figure (PNG)")
    return ap


def pyplot():
    """matplotlib's pyplot on the Agg backend (the examples only write files)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def loss_figure(history, loss_label: str):
    """A two-panel figure of an optimisation: the loss (first column of ``history``) on a log scale
    in the left panel; returns ``(fig, right_axes, history_array, iterations)`` for the caller's
    parameter errors."""
    h = np.asarray(history)
    it = np.arange(len(h))
    fig, ax = pyplot().subplots(1, 2, figsize=(9, 3.4))
    ax[0].semilogy(it, h[:, 0])
    ax[0].set_xlabel("iteration")
    ax[0].set_ylabel(loss_label)
    return fig, ax[1], h, it


def save_figure(fig, path: str):
    """Lay ``fig`` out, write it to ``path`` under a temporary name renamed at the end, and close it."""
    from mitsonar._files import replacing

    fig.tight_layout()
    os.makedirs(os.path.dirname(os.path.abspath(path)) or ".", exist_ok=True)
    with replacing(path) as tmp:
        fig.savefig(tmp, dpi=110, format=os.path.splitext(path)[1][1:] or "png")
    pyplot().close(fig)


def _acoustic(bid, values):
    d, s, n = values
    return (f'<bsdf type="acoustic" id="{bid}"><float name="diffuse" value="{d}"/>'
            f'<float name="specular" value="{s}"/><float name="shininess" value="{n}"/></bsdf>')


def tank_xml(mount, n_pings=24, n_bins=160, range_max=8.0, max_depth=1, walls=(0.5, 0.2, 10.0), floor=None):
    """A tank of known geometry (that of scenes_xml/box.xml: floor z = -3, walls x = +-5 and
    y = +-4, up to z = +9) seen by a mechanical head ``head`` with beam frame ``mount`` (4 x 4)
    sweeping a full turn in ``n_pings`` pings (3 x 35 deg gaussian beam, ``n_bins`` bins from 0 to
    ``range_max``). Materials (acoustic, (diffuse, specular, shininess)): ``wall`` for the walls,
    and the floor's own ``floor`` when ``floor`` is given (else the floor is ``wall`` too)."""
    to_world = " ".join(f"{v:.17g}" for v in np.asarray(mount, dtype=float).ravel())
    step = 360.0 / n_pings
    rect = ('<shape type="rectangle"><transform name="to_world"><scale x="{sx}" y="{sy}"/>{rot}'
            '<translate x="{tx}" y="{ty}" z="{tz}"/></transform><ref id="{mat}"/></shape>')
    fmat = "wall" if floor is None else "floor"
    shapes = [rect.format(sx=5, sy=4, rot="", tx=0, ty=0, tz=-3, mat=fmat),
              rect.format(sx=6, sy=4, rot='<rotate y="1" angle="-90"/>', tx=5, ty=0, tz=3, mat="wall"),
              rect.format(sx=6, sy=4, rot='<rotate y="1" angle="90"/>', tx=-5, ty=0, tz=3, mat="wall"),
              rect.format(sx=5, sy=6, rot='<rotate x="1" angle="90"/>', tx=0, ty=4, tz=3, mat="wall"),
              rect.format(sx=5, sy=6, rot='<rotate x="1" angle="-90"/>', tx=0, ty=-4, tz=3, mat="wall")]
    bsdfs = _acoustic("wall", walls) + ("" if floor is None else _acoustic("floor", floor))
    return (f'<scene version="3.0.0"><integrator type="sonar_tof"><integer name="max_depth" value="{max_depth}"/>'
            f'</integrator><sensor type="sonar" id="head"><string name="kind" value="mechanical"/>'
            f'<transform name="to_world"><matrix value="{to_world}"/></transform>'
            f'<float name="range_min" value="0"/><float name="range_max" value="{range_max}"/>'
            f'<integer name="n_bins" value="{n_bins}"/><float name="bearing_step" value="{step}"/>'
            f'<integer name="n_pings" value="{n_pings}"/><float name="beamwidth_h" value="3"/>'
            f'<float name="beamwidth_v" value="35"/></sensor>' + bsdfs + "".join(shapes) + "</scene>")
