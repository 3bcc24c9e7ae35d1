"""Pictures of a Hilbert map (matplotlib, Agg): cross-sections like thesis Figs. 4.1-4.4 and 5.1
(probability colour map, ground truth as lines) and the half-probability region (Fig. 5.2)."""
from __future__ import annotations

import numpy as np

from . import geometry as geo

DEFAULT_SLICES = (("z", 0.0), ("y", 0.0), ("x", 0.0))


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _truth_lines(ax, truth, axis, value, others, **kw):
    if truth is None:
        return
    V, F = truth
    segs = geo.plane_section(V, F, "xyz".index(axis), value)
    for a, b in segs:
        ax.plot([a[others[0]], b[others[0]]], [a[others[1]], b[others[1]]], **kw)


def _extent_for(hm, axis, truth, pad=1.0):
    a = "xyz".index(axis)
    others = [i for i in range(3) if i != a]
    lo, hi = hm.coverage_.bounds()
    if truth is not None:
        V = np.asarray(truth[0])
        # keep to the part of the geometry the sonar can have seen
        vlo = np.maximum(V.min(axis=0) - pad, lo)
        vhi = np.minimum(V.max(axis=0) + pad, hi)
        lo, hi = vlo, vhi
    return ((lo[others[0]], hi[others[0]]), (lo[others[1]], hi[others[1]])), others


def plot_slices(hm, slices=DEFAULT_SLICES, truth=None, path=None, resolution: float = 0.04, extents=None,
                title: str | None = None, show_unseen: bool = False, level: float = 0.5):
    """Probability cross-sections, one panel per ``(axis, value)``; returns the figure.

    ``truth``: (vertices, faces) drawn as green lines; the ``level`` contour is drawn white and the
    part of each plane the sonar never saw is grey unless ``show_unseen``.
    """
    plt = _plt()
    n = len(slices)
    fig, axes = plt.subplots(1, n, figsize=(5.2 * n, 4.6), squeeze=False)
    im = None
    for k, (axis, value) in enumerate(slices):
        ax = axes[0, k]
        if extents is not None:
            ext = extents[k]
            a = "xyz".index(axis)
            others = [i for i in range(3) if i != a]
        else:
            ext, others = _extent_for(hm, axis, truth)
        sl = hm.slice(axis, value, extent=ext, resolution=resolution)
        img = sl.prob if show_unseen else np.ma.masked_where(~sl.seen, sl.prob)
        cmap = plt.get_cmap("viridis").with_extremes(bad="0.8")
        im = ax.imshow(img, origin="lower", extent=sl.extent, vmin=0.0, vmax=1.0, cmap=cmap, interpolation="nearest")
        if np.nanmin(sl.prob) < level < np.nanmax(sl.prob):
            ax.contour(sl.u, sl.v, sl.prob, levels=[level], colors="w", linewidths=0.8, linestyles="--")
        _truth_lines(ax, truth, axis, value, others, color="lime", lw=1.2)
        ax.set_xlim(sl.extent[0], sl.extent[1])
        ax.set_ylim(sl.extent[2], sl.extent[3])
        ax.set_xlabel(f"{sl.axes[0]} (m)")
        ax.set_ylabel(f"{sl.axes[1]} (m)")
        ax.set_title(f"{axis} = {value:g} m")
        ax.set_aspect("equal")
    fig.colorbar(im, ax=axes[0, :].tolist(), shrink=0.85, label="occupancy probability")
    if title:
        fig.suptitle(title)
    if path is not None:
        fig.savefig(path, dpi=110, bbox_inches="tight")
        plt.close(fig)
    return fig


def plot_half_region(hm, axis="z", value=0.0, truth=None, path=None, resolution: float = 0.03, extent=None,
                     level: float = 0.5, title: str | None = None):
    """The region where p > ``level`` (blue) with the ground truth (green), as thesis Fig. 5.2."""
    plt = _plt()
    from matplotlib.colors import ListedColormap

    if extent is None:
        extent, others = _extent_for(hm, axis, truth)
    else:
        a = "xyz".index(axis)
        others = [i for i in range(3) if i != a]
    sl = hm.slice(axis, value, extent=extent, resolution=resolution)
    fig, ax = plt.subplots(figsize=(6, 5))
    region = np.where(sl.seen, (sl.prob > level).astype(float), np.nan)
    ax.imshow(np.ma.masked_invalid(region), origin="lower", extent=sl.extent,
              cmap=ListedColormap(["white", "tab:blue"]), vmin=0, vmax=1, interpolation="nearest")
    _truth_lines(ax, truth, axis, value, others, color="green", lw=1.5)
    ax.set_xlabel(f"{sl.axes[0]} (m)")
    ax.set_ylabel(f"{sl.axes[1]} (m)")
    ax.set_title(title or f"p > {level:g} at {axis} = {value:g} m")
    ax.set_aspect("equal")
    if path is not None:
        fig.savefig(path, dpi=110, bbox_inches="tight")
        plt.close(fig)
    return fig


def plot_survey_map(hm, path=None, elevation=None, slice_z=None, resolution: float = 0.1, title=None):
    """A plan view of a survey map with the vehicle's track: left, the probability on the
    horizontal slice ``z = slice_z`` (default the track's mean depth); right, the seabed
    elevation grid when one is given (:func:`hilbertmap.elevation.elevation_grid`). The track
    (``hm.track_``, else ``hm.sensor_positions_``) is drawn on both. Returns the figure, saved
    to ``path`` when given."""
    plt = _plt()
    track = np.asarray(getattr(hm, "track_", hm.sensor_positions_))
    z = float(np.mean(track[:, 2])) if slice_z is None and len(track) else float(slice_z or 0.0)
    n = 2 if elevation is not None else 1
    fig, axes = plt.subplots(1, n, figsize=(6.5 * n, 5.5), squeeze=False)
    ax = axes[0, 0]
    sl = hm.slice("z", z, resolution=resolution)
    prob = np.where(sl.seen, sl.prob, np.nan)
    im = ax.imshow(prob, origin="lower", extent=sl.extent, cmap="viridis", vmin=0, vmax=1)
    fig.colorbar(im, ax=ax, label="occupancy probability", shrink=0.8)
    ax.set_title(f"slice z = {z:.2f} m")
    if elevation is not None:
        ax2 = axes[0, 1]
        a, _, c, _, e, f = elevation.transform
        rows, cols = elevation.elevation.shape
        im2 = ax2.imshow(elevation.elevation, extent=(c, c + a * cols, f + e * rows, f), cmap="terrain")
        fig.colorbar(im2, ax=ax2, label="elevation (m)", shrink=0.8)
        ax2.set_title("seabed elevation")
    for a_ in axes[0]:
        if len(track):
            a_.plot(track[:, 0], track[:, 1], "r-", lw=1.2, label="track")
            a_.plot(track[0, 0], track[0, 1], "ro", ms=4)
        a_.set_xlabel("x (m)")
        a_.set_ylabel("y (m)")
        a_.set_aspect("equal")
    axes[0, 0].legend(loc="upper right", fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=120)
        plt.close(fig)
    return fig
