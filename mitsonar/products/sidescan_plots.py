"""Pictures of side-scan products: the waterfall (`plot_waterfall`) and a survey's mosaic
(`plot_mosaic`), drawn like `mitsonar.products.plots` (a ``matplotlib`` Figure, no pyplot; PNG, PDF or SVG
by the extension; written under a temporary name and renamed)."""
from __future__ import annotations

import math

import numpy as np

from mitsonar.products.plots import DEFAULT_CMAP, DEFAULT_DYNAMIC_RANGE, _new_figure, _save, _settings_line
from mitsonar.products.sidescan import ground_range, waterfall


def _db(v, dynamic_range):
    positive = v[np.isfinite(v) & (v > 0)]
    hi = 10.0 * math.log10(float(positive.max())) if positive.size else 0.0
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.maximum(10.0 * np.log10(v), hi - dynamic_range)
    return out, hi - dynamic_range, hi


def plot_waterfall(scan, path=None, ax=None, use: str = "data", ground: bool = False, altitude=None, seabed=None,
                   cmap: str = DEFAULT_CMAP, dynamic_range: float = DEFAULT_DYNAMIC_RANGE, figsize=(9.0, 6.0),
                   dpi: int = 150):
    """The waterfall of a side-scan ``scan``: port mirrored left of starboard (range growing outwards
    from the centre line), the newest ping at the top, as side-scan viewers scroll. ``use``: ``data``
    (device bytes) or ``intensity`` (dB, the top ``dynamic_range`` dB); ``ground=True`` shows the
    ground-range corrected rows (`mitsonar.products.sidescan.ground_range` with ``altitude``/``seabed``).
    Returns the figure."""
    gr = ground_range(scan, use=use, altitude=altitude, seabed=seabed) if ground else None
    img = waterfall(scan, use=use, ground=gr)
    if use == "intensity":
        img, lo, hi = _db(img, dynamic_range)
        label = "echo energy per bin (dB)"
    else:
        lo, hi, label = 0.0, 255.0, "device output (0..255)"
    top = gr.ground[-1] + (gr.ground[1] - gr.ground[0]) / 2 if gr is not None else scan.range_max
    bottom = 0.0 if gr is not None else scan.range_min
    n_rows = img.shape[0]
    times = scan.times[scan.channel == scan.channel[0]]
    fig, ax = _new_figure(ax, figsize, dpi)
    # x: port negative (left), starboard positive; the two halves meet at the head's track
    half = img.shape[1] // 2
    ax.imshow(img[:, :half], extent=(-top, -bottom, 0, n_rows), aspect="auto", cmap=cmap, vmin=lo, vmax=hi,
              interpolation="nearest")
    im = ax.imshow(img[:, half:], extent=(bottom, top, 0, n_rows), aspect="auto", cmap=cmap, vmin=lo, vmax=hi,
                   interpolation="nearest")
    ax.set_xlim(-top, top)
    ax.set_ylim(0, n_rows)
    ax.set_facecolor("0.85")
    ax.set_xlabel(("ground" if ground else "slant") + " range (m): port  <-  |  ->  starboard")
    ax.set_ylabel(f"ping (newest at the top; {times[-1] - times[0]:.3g} s)" if len(times) > 1 else "ping")
    ax.axvline(0.0, color="w", lw=0.5)
    ax.set_title("side-scan waterfall: " + _settings_line(scan), fontsize=7)
    fig.colorbar(im, ax=ax, label=label, fraction=0.04)
    _save(fig, path)
    return fig


def plot_mosaic(m, path=None, ax=None, mesh=None, cmap: str = DEFAULT_CMAP,
                dynamic_range: float = DEFAULT_DYNAMIC_RANGE, track=None, figsize=(8.0, 6.0), dpi: int = 150):
    """A `mitsonar.products.mosaic.Mosaic` in world x-y (metres, north up), optionally with the vehicle's
    ``track`` (a `Trajectory`) and the outline of a ground-truth ``mesh`` (vertices, faces: its
    triangles' x-y edges above the seabed are not distinguished; pass the objects' mesh). Returns
    the figure. `Mosaic.save` writes the bare georeferenced PNG and array."""
    img = m.image
    if m.use == "intensity":
        img, lo, hi = _db(img, dynamic_range)
        label = "echo energy per bin (dB)"
    else:
        lo, hi, label = 0.0, 255.0, "device output (0..255)"
    x0, x1, y0, y1 = m.bounds
    fig, ax = _new_figure(ax, figsize, dpi)
    ax.set_facecolor("0.85")
    im = ax.imshow(img, extent=(x0, x1, y0, y1), origin="upper", cmap=cmap, vmin=lo, vmax=hi,
                   interpolation="nearest")
    if track is not None:
        p = track.positions
        ax.plot(p[:, 0], p[:, 1], color="c", lw=0.8, label="track")
        ax.legend(loc="upper right", fontsize=7)
    if mesh is not None:
        from matplotlib.collections import LineCollection

        v, f = (np.asarray(a) for a in mesh)
        edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        ax.add_collection(LineCollection(v[edges][:, :, :2], colors="w", linewidths=0.2, alpha=0.3))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_aspect("equal")
    ax.set_title(f"side-scan mosaic, {m.resolution:g} m cells", fontsize=8)
    fig.colorbar(im, ax=ax, label=label, fraction=0.04)
    _save(fig, path)
    return fig
