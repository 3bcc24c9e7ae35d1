"""Pictures of a comparison: error versus time (``convergence.png``), polar images (``polar.png``)."""
from __future__ import annotations

import math
import os

import numpy as np


def _figure(figsize, dpi=110, layout=None):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=dpi, layout=layout)
    FigureCanvasAgg(fig)
    return fig


def _log_ticks(axis) -> None:
    """Tick labels of a log axis as plain numbers (0.5, 2, 16; 2e-04 below 1e-3), the minor ticks
    labelled only at 2 and 5 times a power of ten and only where the axis spans less than two
    decades: matplotlib's default labels of a short log axis (``3 x 10^0``, ``4 x 10^0``) run into
    each other."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    def plain(v, _pos=None):
        return f"{v:g}"

    lo, hi = sorted(axis.get_view_interval())
    axis.set_major_formatter(FuncFormatter(plain))
    if lo > 0 and math.log10(hi / lo) < 2.0:
        axis.set_minor_locator(LogLocator(base=10.0, subs=(2.0, 5.0)))
        axis.set_minor_formatter(FuncFormatter(plain))
    else:
        axis.set_minor_formatter(NullFormatter())


def plot_convergence(result, path):
    """Error versus measured seconds, log-log, one line per integrator (rel L2, rel L1, regions).

    Points are the mean seconds and the RMS error of the repeats; the thin dashed line has the
    slope -1/2 of unbiased Monte Carlo, the dotted one is the reference's own error.
    """
    labels = result["settings"]["integrators"]
    regions = list(result["settings"]["regions"])
    panels = [("rel_l2", "relative L2 error (whole scan)"), ("rel_l1", "relative L1 error (whole scan)")]
    panels += [(f"region:{rn}", f"relative L2 error, {rn} ({result['settings']['regions'][rn][0]:g}-"
                                f"{result['settings']['regions'][rn][1]:g} m)") for rn in regions]
    fig = _figure((5.0 * len(panels), 4.2), layout="constrained")
    self_l2 = result["reference"].get("self_rel_l2")
    for i, (key, title) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), i + 1)
        for lab in labels:
            rows = sorted((r for r in result["runs"] if r["integrator"] == lab), key=lambda r: r["budget_s"])
            t = [r["seconds_mean"] for r in rows]
            e = [r["regions"][key.split(":", 1)[1]]["rel_l2"] if key.startswith("region:") else r[key]
                 for r in rows]
            ax.plot(t, e, "o-", label=result.get("integrators", {}).get(lab, {}).get("shown_as", lab))
            for ti, ei, r in zip(t, e, rows):
                ax.annotate(f"{r['spp']}", (ti, ei), textcoords="offset points", xytext=(3, 3), fontsize=6)
        all_t = [r["seconds_mean"] for r in result["runs"]]
        all_e = [r["rel_l2"] for r in result["runs"]] if key == "rel_l2" else None
        if all_e and min(all_t) > 0 and min(all_e) > 0:
            t0, t1 = min(all_t), max(all_t)
            e0 = max(all_e)
            ax.plot([t0, t1], [e0, e0 * math.sqrt(t0 / t1)], "k--", lw=0.6, label="slope -1/2")
        if key == "rel_l2" and self_l2:
            ax.axhline(self_l2, color="0.5", ls=":", lw=0.8, label="reference's own error")
        ax.set_xscale("log")
        ax.set_yscale("log")
        _log_ticks(ax.xaxis)
        _log_ticks(ax.yaxis)
        ax.set_xlabel("measured seconds per render")
        ax.set_ylabel(title.split(" (")[0].split(",")[0])
        ax.set_title(title, fontsize=9)
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
        ax.legend(fontsize=7)
    scene = os.path.basename(result["settings"]["scene"])
    fig.suptitle(f"{scene}: error against a {result['reference']['spp']}-spp sonar_tof reference "
                 f"(spp labelled; {result['settings']['repeats']} repeat(s), RMS)", fontsize=9)
    fig.savefig(path)
    return fig


def scan_from_histogram(sensor, hist, meta=None):
    """A `Scan` of a rendered histogram for pictures: intensity only (device bytes zero)."""
    from mitsonar.scan import Scan, ScanMeta

    hist = np.asarray(hist)
    return Scan(intensity=hist.astype(np.float32), data=np.zeros(hist.shape, np.uint8),
                ranges=sensor.bin_centres(), bearings=np.radians(sensor.bearings_deg()),
                poses=sensor.ping_poses(None), range_min=sensor.range_min, range_max=sensor.range_max,
                beam_pattern=sensor.beam.pattern, beamwidth_h=sensor.beam.beamwidth_h,
                beamwidth_v=sensor.beam.beamwidth_v, kind=sensor.kind, sound_speed=sensor.sound_speed,
                absorption=sensor.absorption, meta=ScanMeta.from_dict(meta or {}))


def _sector_box(scan):
    """``(x0, x1, y0, y1)`` of the fan of a narrow sector in plot_polar's display coordinates,
    or None for a sector of half a turn or more (then the whole disc is shown)."""
    half = math.radians(scan.beamwidth_h) / 2
    b = np.asarray(scan.bearings)
    if b.size == 0 or (b.max() - b.min()) + 2 * half >= math.pi:
        return None
    angles = np.linspace(b.min() - half, b.max() + half, 64)
    r = scan.range_max
    xs = np.concatenate([[0.0], -r * np.sin(angles)])
    ys = np.concatenate([[0.0], r * np.cos(angles)])
    pad = 0.04 * r
    return xs.min() - pad, xs.max() + pad, ys.min() - pad, ys.max() + pad


def plot_polar_grid(sensor, reference, renders, labels, budgets, runs, path, ref_info=None):
    """Polar intensity images (dB, one colour scale: the reference's top 60 dB) side by side.

    One row per integrator; the first column is the reference, then one column per budget
    (the first repeat of each run). A narrow sector is framed tightly (plot_polar draws the
    whole disc). Returns the figure.
    """
    from mitsonar.products.plots import plot_polar

    by = {(r["integrator"], r["budget_s"]): r for r in runs}
    positive = reference[reference > 0]
    hi = 10 * math.log10(float(positive.max())) if positive.size else 0.0
    lo = hi - 60.0
    box = _sector_box(scan_from_histogram(sensor, reference))
    aspect = 1.0 if box is None else (box[1] - box[0]) / (box[3] - box[2])
    panel_h = 3.6
    panel_w = panel_h * aspect + 1.3  # + the colour bar
    cols, rows = 1 + len(budgets), len(labels)
    fig = _figure((panel_w * cols, (panel_h + 0.5) * rows), dpi=100)
    for i, lab in enumerate(labels):
        for j in range(cols):
            ax = fig.add_subplot(rows, cols, i * cols + j + 1)
            if j == 0:
                hist = reference
                title = f"reference\nsonar_tof, {ref_info['spp'] if ref_info else '?'} spp"
            else:
                budget = budgets[j - 1]
                hist = renders[(lab, budget)]
                r = by[(lab, budget)]
                title = (f"{lab}, {budget:g} s budget\n{r['spp']} spp, {r['seconds'][0]:.2g} s, "
                         f"rel L2 {r['rel_l2_each'][0]:.3g}")
            n_axes = len(fig.axes)
            plot_polar(scan_from_histogram(sensor, hist), ax=ax, use="intensity", db=True, vmin=lo, vmax=hi,
                       resolution=500, title=title)
            if box is not None:
                ax.set_xlim(box[0], box[1])
                ax.set_ylim(box[2], box[3])
                # The bearing labels sit outside the frame now: clip them and keep them out of
                # the layout, or tight_layout shrinks every panel to make room for them.
                for t in ax.texts:
                    t.set_clip_on(True)
                    t.set_in_layout(False)
            ax.title.set_fontsize(7)
            ax.tick_params(labelsize=6)
            ax.set_xlabel("m", fontsize=6)
            ax.set_ylabel("m", fontsize=6)
            for cax in fig.axes[n_axes:]:  # the colour bar plot_polar added
                cax.tick_params(labelsize=6)
                cax.yaxis.label.set_fontsize(6)
    fig.tight_layout()
    fig.savefig(path)
    return fig


__all__ = ["plot_convergence", "plot_polar_grid", "scan_from_histogram"]
