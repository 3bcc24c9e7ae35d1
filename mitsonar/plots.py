"""Pictures of a scan: sonar fan display, world top view with ground truth, A-scan; and of a
vehicle's track (`plot_track`).

All functions build a ``matplotlib.figure.Figure`` directly (no pyplot), so no window and no GUI
backend is ever involved; figures render with Agg (PNG) or the vector backends (PDF, SVG) by the
extension of ``path``. Each function returns the figure it drew into.

Values shown (``use`` and ``db``):

============ ======= ==============================================================================
use          db      colour
============ ======= ==============================================================================
``data``     False   device bytes 0..255 (what the head outputs)
``data``     True    the bytes' level on the A/D scale, ``ad_low + byte / 255 * ad_span`` dB
``intensity`` False  noise-free echo energy per bin (linear)
``intensity`` True   ``10 log10`` of it, the top ``dynamic_range`` dB shown (zeros at the bottom)
============ ======= ==============================================================================
"""
from __future__ import annotations

import math
import os
from typing import Any

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.figure import Figure

#: Colour map of the sonar pictures: dark open water, bright echoes (a classic sonar palette).
DEFAULT_CMAP = "copper"
DEFAULT_DYNAMIC_RANGE = 60.0  # dB shown below the brightest intensity when db=True


# ----------------------------------------------------------------------------------------------
# shared helpers

def _values(scan, use: str, db: bool, dynamic_range: float, vmin=None, vmax=None):
    """Values to colour, their limits and the colour-bar label."""
    if use not in ("data", "intensity"):
        raise ValueError(f"plot: use={use!r} is not one of data, intensity")
    if use == "data":
        v = scan.data.astype(np.float64)
        if not db:
            lo, hi, label = 0.0, 255.0, "device output (0..255)"
        else:
            elec = _electronics(scan)
            v = elec["ad_low"] + v / 255.0 * elec["ad_span"]
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
    return {**defaults, **{k: v for k, v in (scan.electronics or {}).items() if k in defaults}}


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
    e = scan.electronics or {}
    elec = []
    if "tvg" in e:
        elec.append(f"TVG {e['tvg']}")
    if "gain" in e:
        elec.append(f"gain {fmt(e['gain'], 1)} dB")
    if "ad_low" in e:
        elec.append(f"AD {fmt(e['ad_low'], 1)}" + (f"+{fmt(e['ad_span'], 1)} dB" if "ad_span" in e else " dB"))
    if "bit_depth" in e:
        elec.append(f"{e['bit_depth']}-bit")
    if "speckle" in e:
        elec.append(f"speckle {e['speckle']}")
    if elec:
        line2.append(", ".join(elec))
    meta = scan.meta or {}
    prov = [f"{k} {meta[k]}" for k in ("scene", "spp", "seed") if k in meta]
    if meta.get("source") == "seanet":
        prov.insert(0, "SeaNet head" + (f" log {os.path.basename(str(meta['log']))}" if "log" in meta else ""))
    if prov:
        line2.append(", ".join(prov))
    # a line that would run off a 7-inch title wraps at the parts' boundary
    sep = "\n" if sum(len(x) + 2 for x in line2) > 95 else "; "
    return ", ".join(parts) + ("\n" + sep.join(line2) if line2 else "")


def _new_figure(ax, figsize, dpi):
    if ax is not None:
        return ax.figure, ax
    fig = Figure(figsize=figsize, dpi=dpi)
    return fig, fig.add_subplot(1, 1, 1)


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

    Each ping is a wedge ``ping_width`` wide centred on its bearing, drawn in ping order so later
    pings cover earlier ones where they overlap (3 deg wedges at 1.8 deg steps). Bearing 0 is at
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
        Wedge width in degrees; default the scan's ``beamwidth_h``.
    vmin, vmax : float, optional
        Colour limits (defaults: 0..255, the A/D window, or the data range).
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

    # Which ping is visible in each direction: paint a fine angular grid in ping order.
    n_cells = 3600
    cell = 2.0 * math.pi / n_cells
    centres = (np.arange(n_cells) + 0.5) * cell
    owner = np.full(n_cells, -1)
    for k, b in enumerate(scan.bearings):
        diff = np.abs((centres - b + math.pi) % (2.0 * math.pi) - math.pi)
        owner[diff <= width / 2.0] = k

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
        # Labelled between the 0 and 330 deg spokes, clear of the bearing labels.
        ax.text(rr * math.sin(math.radians(15)), rr * math.cos(math.radians(15)), f"{rr:g} m", color="0.75",
                fontsize=7, ha="center", va="center")
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


def plot_cartesian(scan, mesh=None, path=None, ax=None, db: bool = False, cmap: str = DEFAULT_CMAP,
                   use: str = "data", ping_width: float | None = None, *, vmin=None, vmax=None,
                   dynamic_range=DEFAULT_DYNAMIC_RANGE, figsize=(7.0, 6.4), dpi: int = 150,
                   title: str | None = None) -> Figure:
    """Top view in world coordinates, with the scene's ground truth cut through the sonar's plane.

    Bin j of ping k sits at ``position_k + ranges[j] * boresight_k``, from the ping's own pose
    (a scan rendered in motion shows its distortion, and the head's path); each ping is drawn as a
    wedge ``ping_width`` wide about its scan axis, projected on the plane perpendicular to the
    (mean) scan axis. When the scan axis is world +z or -z the plot axes are world x and y;
    otherwise an orthonormal basis of that plane (named u, v).

    Parameters
    ----------
    scan : Scan
    mesh : (vertices (V, 3), faces (F, 3)), optional
        Ground-truth triangles (e.g. ``mitsonar.scene_mesh(scene)``); drawn as the segments where
        they cut the plane through the mean sonar position perpendicular to the scan axis.
    path, ax, db, cmap, use, ping_width, vmin, vmax, dynamic_range, figsize, dpi, title
        As in `plot_polar`.

    Returns
    -------
    matplotlib.figure.Figure
    """
    fig, ax = _new_figure(ax, figsize, dpi)
    values, lo, hi, label = _values(scan, use, db, dynamic_range, vmin, vmax)
    width = math.radians(scan.beamwidth_h if ping_width is None else ping_width)
    origin, axis, e1, e2, names = _view_plane(scan)

    r_edges = scan.range_min + np.arange(scan.n_bins + 1) * scan.bin_width
    mesh_artist = None
    for k in range(scan.n_pings):
        pose = scan.poses[k]
        pos, xb, zb = pose[:3, 3], pose[:3, 0], pose[:3, 2]
        # The wedge edges: the boresight turned by -/+ width/2 about the ping's scan axis.
        corners = []
        for phi in (-width / 2.0, width / 2.0):
            d = math.cos(phi) * zb + math.sin(phi) * xb
            p = pos[None, :] + r_edges[:, None] * d[None, :]
            corners.append(np.stack([p @ e1, p @ e2], -1))
        quad = np.stack(corners, 0)  # (2, n_bins + 1, 2)
        mesh_artist = ax.pcolormesh(quad[..., 0], quad[..., 1], values[k][None, :], cmap=cmap,
                                    vmin=lo, vmax=hi, shading="flat", rasterized=True)
    pos2 = np.stack([scan.positions @ e1, scan.positions @ e2], -1)
    if np.ptp(pos2, axis=0).max() > 1e-6:   # a head that moved during the scan: its path, ping 0 marked
        ax.plot(pos2[:, 0], pos2[:, 1], "-", color="tab:cyan", lw=1.2, label="sonar (moving)")
        ax.plot(pos2[:1, 0], pos2[:1, 1], "o", color="tab:cyan", ms=4)
    else:
        ax.plot(pos2[:, 0], pos2[:, 1], "+", color="tab:cyan", ms=8, label="sonar")

    if mesh is not None:
        segments = mesh_section(mesh[0], mesh[1], origin, axis)
        if len(segments):
            seg2 = np.stack([segments @ e1, segments @ e2], -1)
            ax.add_collection(LineCollection(seg2, colors="tab:green", linewidths=1.0, label="ground truth"))
    ax.set_aspect("equal")
    # Frame what the sonar covered; ground truth beyond its range would only shrink the scan.
    pad = 1.05 * scan.range_max
    ax.set_xlim(pos2[:, 0].min() - pad, pos2[:, 0].max() + pad)
    ax.set_ylim(pos2[:, 1].min() - pad, pos2[:, 1].max() + pad)
    ax.set_facecolor("0.85")
    ax.set_xlabel(f"world {names[0]} (m)")
    ax.set_ylabel(f"world {names[1]} (m)")
    ax.legend(loc="upper right", fontsize=7)
    if mesh_artist is not None:
        fig.colorbar(mesh_artist, ax=ax, label=label, shrink=0.85)
    ax.set_title(_settings_line(scan) if title is None else title, fontsize=7)
    _save(fig, path)
    return fig


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
    ax.set_xlabel("world x (m)")
    ax.set_ylabel("world y (m)")
    # below the axes: inside, it covered the track's end on every straight run
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.12), ncol=5, fontsize=7, frameon=False)
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
    own_figure = ax is None
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
    ax2.set_ylim(0, 260)
    ax2.set_ylabel("device output (0..255)", color="tab:orange")
    row = ping % scan.n_pings
    if scan.channel is not None:      # a side-scan row: a ping of one channel, not a bearing
        side = scan.channel[row]
        where = f"ping {row - int(np.argmax(scan.channel == side))} of the {('port', 'starboard')[int(side)]} channel"
    else:
        where = f"{scan.row_name[:-1]} {row}, bearing {fmt(math.degrees(scan.bearings[ping]))} deg"
    ax.set_title((where + "\n" + _settings_line(scan))
                 if title is None else title, fontsize=7)
    if own_figure:
        fig.tight_layout()  # a long settings line wraps the title to three lines: keep it on the page
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


def _view_plane(scan):
    """Origin, scan axis and an in-plane basis (with axis names) for the top view."""
    axis = scan.poses[:, :3, 1].mean(axis=0)
    norm = np.linalg.norm(axis)
    axis = np.array([0.0, 0.0, 1.0]) if norm == 0 else axis / norm
    origin = scan.positions.mean(axis=0)
    if abs(axis[2]) > 0.999:
        e1, e2 = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
        if axis[2] < 0:  # looking from below: keep the view right-handed about the axis
            e2 = -e2
            return origin, axis, e1, e2, ("x", "-y")
        return origin, axis, e1, e2, ("x", "y")
    seed = np.eye(3)[int(np.argmin(np.abs(axis)))]
    e1 = seed - axis * (seed @ axis)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    return origin, axis, e1, e2, ("u", "v")


def _nice_step(rmax: float) -> float:
    """A round ring spacing giving 3 to 8 rings."""
    for step in (0.5, 1, 2, 2.5, 5, 10, 20, 25, 50, 100, 200, 500):
        if rmax / step <= 8:
            return float(step)
    return float(10 ** math.ceil(math.log10(rmax / 8)))
