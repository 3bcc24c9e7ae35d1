"""Pictures of a scan: sonar fan display, world top view with ground truth, A-scan; and of a
vehicle's track (`plot_track`).

All functions build a ``matplotlib.figure.Figure`` directly (no pyplot), so no window and no GUI
backend is ever involved; figures render with Agg (PNG) or the vector backends (PDF, SVG) by the
extension of ``path``. Each function returns the figure it drew into.

Values shown (``use`` and ``db``):

============= ======= =============================================================================
use           db      colour
============= ======= =============================================================================
``data``      False   device codes 0..255 (what the head outputs; 0..65535, 0..4294967295 for the
                      uint16, uint32 data of a 16-, 32-bit A/D)
``data``      True    the codes' level on the A/D scale, ``ad_low + code / full scale * ad_span`` dB
``intensity`` False   noise-free echo energy per bin (linear)
``intensity`` True    ``10 log10`` of it, the top ``dynamic_range`` dB shown (zeros at the bottom)
============= ======= =============================================================================
"""
from __future__ import annotations

import math
import os
import warnings
from typing import Any

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure

from mitsonar.scan.electronics import ElectronicsSettings
from mitsonar.scan.meta import ScanMeta

#: Colour map of the sonar pictures: dark open water, bright echoes (a classic sonar palette).
DEFAULT_CMAP = "copper"
DEFAULT_DYNAMIC_RANGE = 60.0  # dB shown below the brightest intensity when db=True
RING_LABEL_SIZE = 7.0  # points: the range labels of `plot_polar`


# ----------------------------------------------------------------------------------------------
# shared helpers

def _values(scan, use: str, db: bool, dynamic_range: float, vmin=None, vmax=None):
    """Values to colour, their limits and the colour-bar label."""
    if use not in ("data", "intensity"):
        raise ValueError(f"plot: use={use!r} is not one of data, intensity")
    if use == "data":
        v = scan.data.astype(np.float64)
        top = scan.data_full_scale        # 255, or a 16- or 32-bit A/D's 65535, 4294967295
        if not db:
            lo, hi, label = 0.0, float(top), f"device output (0..{top})"
        else:
            elec = _electronics(scan)
            v = elec["ad_low"] + v / top * elec["ad_span"]
            lo, hi = elec["ad_low"], elec["ad_low"] + elec["ad_span"]
            label = "level on the A/D scale (dB)"
    else:
        v = scan.intensity.astype(np.float64)
        if not db:
            hi = float(v.max()) if v.size else 1.0
            lo, label = 0.0, "echo energy per bin (linear)"
            if hi <= 0:
                hi = 1.0
        else:
            positive = v[v > 0]
            hi = 10.0 * math.log10(float(positive.max())) if positive.size else 0.0
            lo = hi - dynamic_range
            with np.errstate(divide="ignore"):
                v = 10.0 * np.log10(v)
            v = np.maximum(v, lo)  # zeros (-inf) sit at the bottom of the scale
            label = "echo energy per bin (dB)"
    lo = lo if vmin is None else vmin
    hi = hi if vmax is None else vmax
    if hi <= lo:
        hi = lo + 1.0
    return v, lo, hi, label


def _electronics(scan) -> dict[str, Any]:
    from mitsonar.receiver.electronics import Electronics

    defaults = Electronics().to_dict()
    given = ElectronicsSettings.from_dict(getattr(scan, "electronics", None) or {})
    return {**defaults, **{k: v for k, v in given.to_dict().items() if k in defaults}}


def fmt(value, decimals: int = 2) -> str:
    """A number for a title: at most ``decimals`` decimals, trailing zeros dropped (27.8095 -> 27.8
    with 1, 0.254899 -> 0.25 with 2, 12.0 -> 12)."""
    text = f"{float(value):.{decimals}f}"
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


def rows_text(scan) -> str:
    """What a scan's rows are, counted: ``200 pings``, ``64 beams``; a two-sided side-scan scan's
    ``250 pings per side`` (its rows are both channels' pings)."""
    channel = scan.channel
    if channel is not None and len(np.unique(channel)) == 2:
        return f"{int(np.sum(channel == channel[0]))} {scan.row_name} per side"
    return f"{scan.n_pings} {scan.row_name}"


def _settings_line(scan) -> str:
    """Key settings for a title: geometry, beam, electronics, provenance. Only the electronics
    settings the scan records are named (a real head's scan records its gain, A/D window and bit
    depth, not the simulator's TVG law or speckle model)."""
    parts = [f"{scan.kind}, {rows_text(scan)} x {scan.n_bins} bins, {fmt(scan.range_min)}-{fmt(scan.range_max)} m",
             f"{scan.beam_pattern} {fmt(scan.beamwidth_h)}x{fmt(scan.beamwidth_v)} deg"]
    line2 = []
    e = ElectronicsSettings.from_dict(getattr(scan, "electronics", None) or {})
    elec = []
    if e.tvg is not None:
        elec.append(f"TVG {e.tvg}")
    if e.gain is not None:
        elec.append(f"gain {fmt(e.gain, 1)} dB")
    if e.ad_low is not None:
        elec.append(f"AD {fmt(e.ad_low, 1)}" + (f"+{fmt(e.ad_span, 1)} dB" if e.ad_span is not None else " dB"))
    if e.bit_depth is not None:
        elec.append(f"{e.bit_depth}-bit")
    if e.speckle is not None:
        elec.append(f"speckle {e.speckle}")
    if elec:
        line2.append(", ".join(elec))
    meta = ScanMeta.from_dict(getattr(scan, "meta", None) or {})
    prov = [f"{k} {getattr(meta, k)}" for k in ("scene", "spp", "seed") if getattr(meta, k) is not None]
    if meta.source == "seanet":
        prov.insert(0, "SeaNet head" + (f" log {os.path.basename(str(meta.log))}" if meta.log is not None else ""))
    if prov:
        line2.append(", ".join(prov))
    # a line that would run off a 7-inch title wraps at the parts' boundary
    sep = "\n" if sum(len(x) + 2 for x in line2) > 95 else "; "
    return ", ".join(parts) + ("\n" + sep.join(line2) if line2 else "")


def _new_figure(ax, figsize, dpi):
    """The figure and axes to draw into: ``ax``'s, or a new figure whose titles, labels, colour bar
    and legend matplotlib's constrained layout places."""
    if ax is not None:
        return ax.figure, ax
    fig = Figure(figsize=figsize, dpi=dpi, layout="constrained")
    return fig, fig.add_subplot(1, 1, 1)


def _legend_below(fig, ax, own_figure: bool, ncol: int) -> None:
    """The legend under the axes (inside, it covers the echoes or the track): on a figure of our
    own the layout engine makes room for it; in a caller's axes it goes where it covers least."""
    if own_figure:
        fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncol=ncol, fontsize=7,
                   frameon=False)
    else:
        ax.legend(loc="best", fontsize=7)


#: Adjacent rows share their wedge's edge (`wedge_edges`) when their boresights are at most this
#: many beamwidths apart; rows further apart keep their own beamwidth.
TILE_MAX_STEP = 2.0


def wedge_edges(step, width: float):
    """``(lo, hi)``: the angles (radians) of each row's wedge edges from its boresight, ``lo < 0 <
    hi``, so that rows next to each other tile the fan with no gap and no overlap.

    ``step`` (n - 1,) is the signed angle from row k's boresight to row k + 1's, NaN where the two
    are not neighbours (another head position or scan axis). Neighbours at most `TILE_MAX_STEP`
    times ``width`` apart share the edge half-way between their boresights; a row with such a
    neighbour on one side only mirrors that edge on its other side (the ends of a fan); any other
    side is ``width / 2`` from the boresight.
    """
    step = np.asarray(step, dtype=np.float64)
    n = step.size + 1
    lo, hi = np.full(n, -width / 2.0), np.full(n, width / 2.0)
    shared_lo, shared_hi = np.zeros(n, bool), np.zeros(n, bool)
    for k, s in enumerate(step):
        if not (np.isfinite(s) and 0.0 < abs(s) <= TILE_MAX_STEP * width):
            continue
        if s > 0:
            hi[k], lo[k + 1] = s / 2.0, -s / 2.0
            shared_hi[k] = shared_lo[k + 1] = True
        else:
            lo[k], hi[k + 1] = s / 2.0, -s / 2.0
            shared_lo[k] = shared_hi[k + 1] = True
    one = shared_lo & ~shared_hi
    hi[one] = -lo[one]
    one = shared_hi & ~shared_lo
    lo[one] = -hi[one]
    return lo, hi


def _save(fig: Figure, path) -> None:
    if path is None:
        return
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower().lstrip(".")
    supported = fig.canvas.get_supported_filetypes()
    if ext not in supported:
        raise ValueError(f"plot: cannot write {path!r}: the extension must be one of "
                         + ", ".join("." + e for e in ("png", "pdf", "svg")))
    from mitsonar._files import replacing

    with replacing(path) as tmp:  # a failed plot leaves no half-written file
        fig.savefig(tmp, dpi=fig.dpi, format=ext)


# ----------------------------------------------------------------------------------------------

def plot_polar(scan, path=None, ax=None, db: bool = False, cmap: str = DEFAULT_CMAP, use: str = "data",
               ping_width: float | None = None, *, vmin=None, vmax=None, dynamic_range=DEFAULT_DYNAMIC_RANGE,
               resolution: int = 900, figsize=(7.0, 6.4), dpi: int = 150, title: str | None = None) -> Figure:
    """Sonar fan display (thesis Fig. 2.15/2.16): range outward, bearing around the head.

    Each ping is a wedge about its bearing, drawn in ping order so later pings cover earlier ones
    where they overlap. By default consecutive pings (a multibeam frame's beams, a mechanical
    head's steps) share the edge half-way between their bearings, so the fan has neither gaps nor
    overlaps (`wedge_edges`); with ``ping_width`` every wedge is that wide, centred on its bearing
    (3 deg wedges at 1.8 deg steps overlap). Bearing 0 is at
    the top and bearings increase counter-clockwise (for a head whose scan axis points up and
    whose boresight at bearing 0 is world +x, this is the world seen from above with +x up).

    Parameters
    ----------
    scan : Scan
    path : str or path-like, optional
        Write the figure here; ``.png``, ``.pdf`` or ``.svg`` by extension.
    ax : matplotlib Axes, optional
        Draw into these (Cartesian) axes instead of a new figure.
    db : bool
        dB instead of linear colours (see the module table).
    cmap : str
        Matplotlib colour map.
    use : ``data`` or ``intensity``
        Device bytes or noise-free echo energy.
    ping_width : float, optional
        Wedge width in degrees; default: consecutive pings tile the fan, a ping without neighbours
        is the scan's ``beamwidth_h`` wide.
    vmin, vmax : float, optional
        Colour limits (defaults: 0..255 (0..65535, 0..4294967295 for wider data), the A/D window,
        or the data range).
    dynamic_range : float
        dB shown below the maximum for ``use='intensity', db=True``.
    resolution : int
        The fan is rasterised on a ``resolution`` x ``resolution`` pixel grid.
    figsize, dpi
        Size of a new figure in inches and its resolution (the PNG is figsize * dpi pixels).
    title : str, optional
        Replaces the default title (the key settings).

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, ax = _new_figure(ax, figsize, dpi)
    values, lo, hi, label = _values(scan, use, db, dynamic_range, vmin, vmax)
    width = math.radians(scan.beamwidth_h if ping_width is None else ping_width)
    rmax = scan.range_max
    bearings = np.asarray(scan.bearings, dtype=np.float64)
    step = (np.diff(bearings) + math.pi) % (2.0 * math.pi) - math.pi
    edge_lo, edge_hi = wedge_edges(step if ping_width is None else np.full(step.shape, np.nan), width)

    # Which ping is visible in each direction: paint a fine angular grid in ping order.
    n_cells = 3600
    cell = 2.0 * math.pi / n_cells
    centres = (np.arange(n_cells) + 0.5) * cell
    owner = np.full(n_cells, -1)
    for k, b in enumerate(bearings):
        diff = (centres - b + math.pi) % (2.0 * math.pi) - math.pi
        owner[(diff >= edge_lo[k]) & (diff <= edge_hi[k])] = k

    # Display coordinates: x right, y up; bearing 0 up, counter-clockwise positive.
    edges = np.linspace(-rmax, rmax, resolution + 1)
    mid = 0.5 * (edges[:-1] + edges[1:])
    x, y = np.meshgrid(mid, mid[::-1])  # image row 0 is the top
    r = np.hypot(x, y)
    theta = np.arctan2(-x, y) % (2.0 * math.pi)
    ping = owner[np.minimum((theta / cell).astype(int), n_cells - 1)]
    bins = np.floor((r - scan.range_min) / scan.bin_width).astype(int)
    inside = (ping >= 0) & (bins >= 0) & (bins < scan.n_bins)
    image = np.full(r.shape, np.nan)
    image[inside] = values[ping[inside], bins[inside]]

    ax.set_facecolor("0.85")  # directions no ping covered
    im = ax.imshow(image, extent=(-rmax, rmax, -rmax, rmax), origin="upper", cmap=cmap, vmin=lo, vmax=hi,
                   interpolation="nearest")
    # Range rings and bearing spokes, labelled: a sonar operator's grid.
    ring_step = _nice_step(rmax)
    t = np.linspace(0, 2 * math.pi, 361)
    for rr in np.arange(ring_step, rmax + 1e-9, ring_step):
        ax.plot(-rr * np.sin(t), rr * np.cos(t), color="0.6", lw=0.4, alpha=0.7)
        # Labelled between the 0 and 330 deg spokes, clear of the bearing labels, just inside
        # their ring (the outer one is the rim of the fan: a label on it would cross it): centred
        # under a point of the ring, lowered by what the ring drops (slope tan 15 deg) across
        # half the label's width (about 0.6 em a character).
        text = f"{rr:g} m"
        drop = 1.5 + math.tan(math.radians(20)) * 0.3 * RING_LABEL_SIZE * len(text)
        ax.annotate(text, (rr * math.sin(math.radians(15)), rr * math.cos(math.radians(15))),
                    xytext=(0, -drop), textcoords="offset points", color="0.75", fontsize=RING_LABEL_SIZE,
                    ha="center", va="top")
    for deg in range(0, 360, 30):
        a = math.radians(deg)
        ax.plot([0, -rmax * math.sin(a)], [0, rmax * math.cos(a)], color="0.6", lw=0.4, alpha=0.7)
        ax.text(-1.04 * rmax * math.sin(a), 1.04 * rmax * math.cos(a), f"{deg}\N{DEGREE SIGN}",
                fontsize=7, ha="center", va="center")
    ax.set_xlim(-1.1 * rmax, 1.1 * rmax)
    ax.set_ylim(-1.1 * rmax, 1.1 * rmax)
    ax.set_aspect("equal")
    ax.set_xlabel("m (bearing 0 up, positive bearings counter-clockwise)")
    ax.set_ylabel("m")
    fig.colorbar(im, ax=ax, label=label, shrink=0.85)
    ax.set_title(_settings_line(scan) if title is None else title, fontsize=7)
    _save(fig, path)
    return fig


#: Axis labels of the top views (`plot_cartesian`, `plot_track`): world x is east, y north (ENU).
X_LABEL, Y_LABEL = "world x, east (m)", "world y, north (m)"


def plot_cartesian(scan, mesh=None, path=None, ax=None, db: bool = False, cmap: str = DEFAULT_CMAP,
                   use: str = "data", ping_width: float | None = None, *, vmin=None, vmax=None,
                   dynamic_range=DEFAULT_DYNAMIC_RANGE, figsize=(7.0, 6.4), dpi: int = 150,
                   title: str | None = None) -> Figure:
    """Top view in world coordinates (x east to the right, y north up, equal aspect, metres, as
    `plot_track`), with the scene's ground truth inside the beams.

    Bin j of ping k sits at ``position_k + ranges[j] * boresight_k``, from the ping's own pose
    (a scan rendered in motion shows its distortion, and the head's path), seen from above; each
    ping is drawn as a wedge about its scan axis: consecutive pings from one position and scan axis
    (a multibeam frame's beams, a still mechanical head's steps) share the edge half-way between
    their boresights, so the fan has no gaps (`wedge_edges`); others, or all with ``ping_width``,
    are that wide (default ``beamwidth_h``). A tilted head's wedges are their beam-axis positions
    seen from above (slant range shortened by the tilt's cosine). A head whose sweep is a vertical
    plane (its scan axis, ``poses[k][:3, 1]``, horizontal for every ping: a real head's driver
    with the default identity ``pose`` looks up from the origin) has no width seen from above: a
    `UserWarning` says so and names the pose.

    Parameters
    ----------
    scan : Scan
    mesh : (vertices (V, 3), faces (F, 3)), optional
        Ground-truth triangles (e.g. ``mitsonar.scene_mesh(scene)``), drawn only where an echo can
        come from (`beam_ground_truth`): their horizontal cuts every few decimetres or metres of
        depth, where a ping's beam holds them (between range_min and range_max, within the wedge
        and the -3 dB vertical fan). Walls and piles in reach show as their outline, a sloping
        seabed as contours inside the footprint, a flat seabed not at all.
    path, ax, db, cmap, use, ping_width, vmin, vmax, dynamic_range, figsize, dpi, title
        As in `plot_polar`.

    Returns
    -------
    matplotlib.figure.Figure
    """
    own_figure = ax is None
    fig, ax = _new_figure(ax, figsize, dpi)
    values, lo, hi, label = _values(scan, use, db, dynamic_range, vmin, vmax)
    width = math.radians(scan.beamwidth_h if ping_width is None else ping_width)
    poses = np.asarray(scan.poses, dtype=np.float64)
    if scan.n_pings and np.abs(poses[:, 2, 1]).max() < 1e-6:
        warnings.warn(f"plot_cartesian: the scan axis of every ping (poses[k][:3, 1]) is horizontal, so each "
                      f"sweep is a vertical plane with no width seen from above and the picture shows no "
                      f"echoes; give the head a pose whose scan axis points up (a driver's pose=..., not the "
                      f"default identity), or draw it with plot_polar", UserWarning, stacklevel=2)

    r_edges = scan.range_min + np.arange(scan.n_bins + 1) * scan.bin_width
    mesh_artist = None
    for rows, angles in _wedge_runs(poses, width, tile=ping_width is None):
        # One mesh per run of neighbouring pings, so that they share the vertices of their edges.
        pose = poses[rows.start]
        pos, xb, zb = pose[:3, 3], pose[:3, 0], pose[:3, 2]
        d = np.cos(angles)[:, None] * zb + np.sin(angles)[:, None] * xb         # (m + 1, 3) edge directions
        p = pos + r_edges[None, :, None] * d[:, None, :]                        # (m + 1, n_bins + 1, 3)
        mesh_artist = ax.pcolormesh(p[..., 0], p[..., 1], values[rows], cmap=cmap, vmin=lo, vmax=hi,
                                    shading="flat", rasterized=True)
    pos2 = np.asarray(scan.positions)[:, :2]
    if np.ptp(pos2, axis=0).max() > 1e-6:   # a head that moved during the scan: its path, ping 0 marked
        ax.plot(pos2[:, 0], pos2[:, 1], "-", color="tab:cyan", lw=1.2, label="sonar (moving)")
        ax.plot(pos2[:1, 0], pos2[:1, 1], "o", color="tab:cyan", ms=4)
    else:
        ax.plot(pos2[:1, 0], pos2[:1, 1], "+", color="tab:cyan", ms=8, label="sonar")

    if mesh is not None:
        segments, dz = beam_ground_truth(scan, mesh[0], mesh[1], ping_width)
        ax.add_collection(LineCollection(
            segments[..., :2], colors="tab:green", linewidths=1.4,
            label=f"scene cut every {dz:g} m of depth, inside the beams ({scan.beamwidth_v:g}\N{DEGREE SIGN} fan)"))
    ax.set_aspect("equal")
    # Frame what the sonar covered; ground truth beyond its range would only shrink the scan.
    pad = 1.05 * scan.range_max
    ax.set_xlim(pos2[:, 0].min() - pad, pos2[:, 0].max() + pad)
    ax.set_ylim(pos2[:, 1].min() - pad, pos2[:, 1].max() + pad)
    ax.set_facecolor("0.85")
    ax.set_xlabel(X_LABEL)
    ax.set_ylabel(Y_LABEL)
    _legend_below(fig, ax, own_figure, ncol=2)
    if mesh_artist is not None:
        fig.colorbar(mesh_artist, ax=ax, label=label, shrink=0.85)
    ax.set_title(_settings_line(scan) if title is None else title, fontsize=7)
    _save(fig, path)
    return fig


def _wedge_runs(poses, width: float, tile: bool):
    """``(rows, angles)`` for each run of consecutive pings drawn as one mesh: ``rows`` a slice,
    ``angles`` (m + 1,) the run's wedge edges in radians about its first ping's scan axis, from its
    boresight towards its x axis. Consecutive pings at one position with one scan axis, turning
    the same way, form a run whose edges `wedge_edges` shares; without ``tile`` every ping is its
    own run, ``width`` wide."""
    n = len(poses)
    step = np.full(max(n - 1, 0), np.nan)
    if tile and n > 1:
        a, b = poses[:-1], poses[1:]
        same = ((np.linalg.norm(a[:, :3, 3] - b[:, :3, 3], axis=1) <= 1e-9 * max(1.0, np.abs(poses[:, :3, 3]).max()))
                & (np.linalg.norm(a[:, :3, 1] - b[:, :3, 1], axis=1) <= 1e-9))
        turn = np.arctan2(np.einsum("ki,ki->k", b[:, :3, 2], a[:, :3, 0]),
                          np.einsum("ki,ki->k", b[:, :3, 2], a[:, :3, 2]))
        step = np.where(same, turn, np.nan)
    lo, hi = wedge_edges(step, width)
    joined = np.isfinite(step) & (np.abs(step) > 0) & (np.abs(step) <= TILE_MAX_STEP * width)
    k0 = 0
    while k0 < n:
        k1 = k0 + 1
        sign = 0.0
        while k1 < n and joined[k1 - 1] and (sign == 0.0 or np.sign(step[k1 - 1]) == sign):
            sign = np.sign(step[k1 - 1])
            k1 += 1
        centres = np.concatenate([[0.0], np.cumsum(step[k0:k1 - 1])])   # boresights about ping k0's axis
        if sign >= 0:
            angles = np.concatenate([[lo[k0]], centres + hi[k0:k1]])
        else:
            angles = np.concatenate([[hi[k0]], centres + lo[k0:k1]])
        yield slice(k0, k1), angles
        k0 = k1


#: `beam_ground_truth` cuts the scene at most this many depths (round steps, see `_depth_step`).
GROUND_TRUTH_LEVELS = 12


def beam_ground_truth(scan, vertices, faces, ping_width: float | None = None, step: float | None = None):
    """``(segments (S, 2, 3), dz)``: the scene cut by horizontal planes every ``dz`` metres of
    depth (at ``(k + 1/2) dz``, at most `GROUND_TRUTH_LEVELS` of them over the heights of the
    triangles in reach), kept in pieces at most ``step`` long (default 1/200 of the range window)
    whose midpoint some ping's beam holds (`in_beams`: range, wedge, -3 dB vertical fan).

    Seen from above, the cuts of a wall or a pile fall on one outline, drawn where the beams
    reach it at any depth; a sloping seabed shows as its contours inside the footprint; a flat
    one, which no plane between steps cuts, is not drawn. Nothing is drawn where no ping looks:
    the plane of a tilted head's sweep, cut whole, draws a line across the seabed or a quay
    beyond the range, where no echo can come from.
    """
    V = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    Fc = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    pos = np.asarray(scan.poses, dtype=np.float64)[:, :3, 3]
    reach = float(scan.range_max)
    lo, hi = pos.min(axis=0) - reach, pos.max(axis=0) + reach
    if len(Fc):   # only the triangles whose box meets the box the pings reach
        tri = V[Fc]
        Fc = Fc[np.all((tri.max(axis=1) >= lo) & (tri.min(axis=1) <= hi), axis=1)]
    empty = np.zeros((0, 2, 3))
    if not len(Fc):
        return empty, 0.0
    z = V[Fc][..., 2]
    z0, z1 = max(float(z.min()), lo[2]), min(float(z.max()), hi[2])
    dz = _depth_step(max(z1 - z0, 1e-6) / GROUND_TRUTH_LEVELS)
    levels = (np.arange(math.floor(z0 / dz), math.ceil(z1 / dz)) + 0.5) * dz
    seg = [mesh_section(V, Fc, [0.0, 0.0, zl], [0.0, 0.0, 1.0]) for zl in levels if z0 < zl < z1]
    seg = np.concatenate(seg) if seg else empty
    if not len(seg):
        return empty, dz
    step = (scan.range_max - scan.range_min) / 200.0 if step is None else float(step)
    # pieces of at most `step`: (P, 2, 3)
    length = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1)
    n = np.maximum(1, np.ceil(length / step).astype(int))
    which = np.repeat(np.arange(len(seg)), n)
    i = np.arange(len(which)) - np.repeat(np.cumsum(n) - n, n)
    t0, t1 = i / n[which], (i + 1) / n[which]
    a, d = seg[which, 0], seg[which, 1] - seg[which, 0]
    pieces = np.stack([a + t0[:, None] * d, a + t1[:, None] * d], 1)
    return pieces[in_beams(scan, pieces.mean(axis=1), ping_width)], dz


def _depth_step(at_least: float) -> float:
    """The smallest round step (1, 2, 2.5 or 5 times a power of ten) of at least ``at_least``."""
    e = 10.0 ** math.floor(math.log10(at_least))
    for m in (1.0, 2.0, 2.5, 5.0, 10.0):
        if m * e >= at_least * (1 - 1e-9):
            return float(f"{m * e:.3g}")
    return 10.0 * e


def in_beams(scan, points, ping_width: float | None = None, chunk: int = 1 << 20) -> np.ndarray:
    """Whether each (N, 3) world point lies inside some ping's beam: range within
    [range_min, range_max], the angle about the scan axis within ``ping_width``/2 (default
    ``beamwidth_h``/2) of the boresight, the elevation out of the sweep plane within
    ``beamwidth_v``/2."""
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    half_h = 0.5 * math.radians(scan.beamwidth_h if ping_width is None else ping_width)
    half_v = 0.5 * math.radians(scan.beamwidth_v)
    poses = np.asarray(scan.poses, dtype=np.float64)
    out = np.zeros(len(P), bool)
    per = max(1, chunk // max(len(P), 1))
    for k0 in range(0, len(poses), per):
        T = poses[k0:k0 + per]
        loc = np.einsum("kji,pkj->pki", T[:, :3, :3], P[:, None, :] - T[None, :, :3, 3])   # (N, K, 3) in the beam frame
        r = np.linalg.norm(loc, axis=-1)
        horiz = np.hypot(loc[..., 0], loc[..., 2])
        ok = ((r >= scan.range_min) & (r <= scan.range_max)
              & (np.abs(np.arctan2(loc[..., 0], loc[..., 2])) <= half_h)
              & (np.abs(np.arctan2(loc[..., 1], horiz)) <= half_v))
        out |= ok.any(axis=1)
    return out


#: `plot_track`: the shorter side of the top view is at least this share of the longer.
TRACK_MIN_ASPECT = 0.4


def plot_track(trajectory, path=None, ax=None, scans=(), mesh=None, *, figsize=(7.0, 6.4), dpi: int = 150,
               title: str | None = None) -> Figure:
    """Top view (world x, y) of a vehicle's track: the trajectory's positions, its start and end,
    its heading every tenth of the way, the transducer positions of ``scans`` (each scan's pings
    as dots, so the sweeps along the track show) and, given a ``mesh``, the ground truth where it
    crosses the horizontal plane at the track's mean depth. The view frames all of these, its
    shorter side at least `TRACK_MIN_ASPECT` of the longer.

    Parameters
    ----------
    trajectory : Trajectory (anything with ``positions`` (N, 3), ``poses`` (N, 4, 4), ``span``)
    path, ax, figsize, dpi, title
        As in `plot_polar`.
    scans : iterable of Scan, optional
    mesh : (vertices (V, 3), faces (F, 3)), optional
        Ground-truth triangles (e.g. ``mitsonar.scene_mesh(scene)``), as in `plot_cartesian`.
    """
    own_figure = ax is None
    fig, ax = _new_figure(ax, figsize, dpi)
    p = np.asarray(trajectory.positions)
    framed = [p[:, :2]] + [np.asarray(s.positions)[:, :2] for s in scans]
    if mesh is not None:
        segments = mesh_section(mesh[0], mesh[1], [0.0, 0.0, float(p[:, 2].mean())], [0.0, 0.0, 1.0])
        if len(segments):
            ax.add_collection(LineCollection(segments[..., :2], colors="tab:green", linewidths=1.0,
                                             label=f"ground truth at z = {p[:, 2].mean():.3g} m"))
            framed.append(segments[..., :2].reshape(-1, 2))
    ax.plot(p[:, 0], p[:, 1], "-", color="tab:blue", lw=1.0, label="track")
    ax.plot(p[0, 0], p[0, 1], "o", color="tab:green", label="start")
    ax.plot(p[-1, 0], p[-1, 1], "s", color="tab:red", label="end")
    every = max(1, len(p) // 10)
    heads = np.asarray(trajectory.poses)[::every, :3, 0]
    ax.quiver(p[::every, 0], p[::every, 1], heads[:, 0], heads[:, 1], color="tab:blue", width=0.004,
              angles="xy", scale_units="inches", scale=4.0)
    for i, scan in enumerate(scans):
        q = scan.positions
        ax.plot(q[:, 0], q[:, 1], ".", ms=1.5, color="tab:orange", label="pings" if i == 0 else None)
    # Equal axes, with the shorter side at least TRACK_MIN_ASPECT of the longer: a straight run
    # is otherwise drawn as a strip a few pixels high under its own legend.
    pts = np.concatenate(framed)
    lo_xy, hi_xy = pts.min(axis=0), pts.max(axis=0)
    centre, half = (lo_xy + hi_xy) / 2.0, (hi_xy - lo_xy) / 2.0
    half = np.maximum(half, TRACK_MIN_ASPECT * half.max()) + 0.08 * half.max() + 1e-6
    ax.set_xlim(centre[0] - half[0], centre[0] + half[0])
    ax.set_ylim(centre[1] - half[1], centre[1] + half[1])
    ax.set_aspect("equal")
    ax.set_xlabel(X_LABEL)
    ax.set_ylabel(Y_LABEL)
    # below the axes: inside, it covered the track's end on every straight run
    _legend_below(fig, ax, own_figure, ncol=5)
    lo, hi = trajectory.span
    ax.set_title(f"track: {len(p)} poses, {hi - lo:.6g} s, {np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1)):.6g} m"
                 if title is None else title, fontsize=8)
    _save(fig, path)
    return fig


def plot_ascan(scan, ping: int, path=None, ax=None, db: bool = False, *,
               dynamic_range=DEFAULT_DYNAMIC_RANGE, figsize=(7.0, 4.0), dpi: int = 150,
               title: str | None = None) -> Figure:
    """One ping versus range: echo intensity (left axis) and device bytes (right axis).

    Parameters
    ----------
    scan : Scan
    ping : int
        Ping index (negative counts from the end).
    path, ax, figsize, dpi, title
        As in `plot_polar`.
    db : bool
        Intensity in dB (the top ``dynamic_range`` dB) instead of linear.
    dynamic_range : float

    Returns
    -------
    matplotlib.figure.Figure
    """
    if not -scan.n_pings <= ping < scan.n_pings:
        raise IndexError(f"plot_ascan: {scan.row_name[:-1]} {ping} is out of range for a scan of "
                         f"{scan.n_pings} {scan.row_name}")
    fig, ax = _new_figure(ax, figsize, dpi)
    inten = scan.intensity[ping].astype(np.float64)
    if db:
        positive = inten[inten > 0]
        hi = 10.0 * math.log10(float(positive.max())) if positive.size else 0.0
        lo = hi - dynamic_range
        with np.errstate(divide="ignore"):
            inten = np.maximum(10.0 * np.log10(inten), lo)  # zeros drawn at the bottom
        ax.set_ylim(lo, hi + 3.0)
        label = "echo energy per bin (dB)"
    else:
        label = "echo energy per bin (linear)"
    ax.plot(scan.ranges, inten, color="tab:blue", lw=0.9, label="intensity")
    ax.set_xlabel("range (m)")
    ax.set_ylabel(label, color="tab:blue")
    ax.set_xlim(scan.range_min, scan.range_max)
    ax2 = ax.twinx()
    ax2.step(scan.ranges, scan.data[ping], where="mid", color="tab:orange", lw=0.7, alpha=0.8, label="data")
    top = scan.data_full_scale
    ax2.set_ylim(0, top * 260 / 255)
    ax2.set_ylabel(f"device output (0..{top})", color="tab:orange")
    row = ping % scan.n_pings
    if scan.channel is not None:      # a side-scan row: a ping of one channel, not a bearing
        side = scan.channel[row]
        where = f"ping {row - int(np.argmax(scan.channel == side))} of the {('port', 'starboard')[int(side)]} channel"
    else:
        where = f"{scan.row_name[:-1]} {row}, bearing {fmt(math.degrees(scan.bearings[ping]))} deg"
    ax.set_title((where + "\n" + _settings_line(scan))
                 if title is None else title, fontsize=7)
    _save(fig, path)
    return fig


# ----------------------------------------------------------------------------------------------
# geometry

def mesh_section(vertices, faces, origin, normal) -> np.ndarray:
    """Segments where triangles cross a plane.

    Parameters
    ----------
    vertices : array_like (V, 3)
    faces : array_like (F, 3) of vertex indices
    origin : array_like (3,)
        A point of the plane.
    normal : array_like (3,)
        Plane normal (need not be unit).

    Returns
    -------
    ndarray (S, 2, 3)
        End points of the segments (triangles lying in the plane are left out).
    """
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if f.size == 0:
        return np.zeros((0, 2, 3))
    n = np.asarray(normal, dtype=np.float64)
    s = (v - np.asarray(origin, dtype=np.float64)) @ (n / np.linalg.norm(n))
    tri, ds = v[f], s[f]  # (F, 3, 3), (F, 3)
    above = ds >= 0  # a vertex on the plane counts as above: each crossing is found once
    points = []
    for a, b in ((0, 1), (1, 2), (2, 0)):
        cross = above[:, a] != above[:, b]
        t = np.where(cross, ds[:, a] / np.where(cross, ds[:, a] - ds[:, b], 1.0), 0.0)
        points.append((tri[:, a] + t[:, None] * (tri[:, b] - tri[:, a]), cross))
    pts = np.stack([p for p, _ in points], 1)  # (F, 3 edges, 3)
    crossed = np.stack([c for _, c in points], 1)  # (F, 3)
    keep = crossed.sum(1) == 2
    pts, crossed = pts[keep], crossed[keep]
    order = np.argsort(~crossed, axis=1, kind="stable")[:, :2]
    return np.take_along_axis(pts, order[:, :, None], axis=1)


def _nice_step(rmax: float) -> float:
    """A round ring spacing giving 3 to 8 rings."""
    for step in (0.5, 1, 2, 2.5, 5, 10, 20, 25, 50, 100, 200, 500):
        if rmax / step <= 8:
            return float(step)
    return float(10 ** math.ceil(math.log10(rmax / 8)))
