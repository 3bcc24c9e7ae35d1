"""Pictures of SAS images: the point-spread function (`plot_psf`).

Built on a ``matplotlib.figure.Figure`` directly (no pyplot), as `mitsonar.products.plots`.
"""
from __future__ import annotations

import numpy as np


def plot_psf(image, path=None, *, dynamic_range=40.0, title=None, figsize=(8.0, 3.4), dpi=100):
    """A `SASImage` around a point target: left the image in dB re its peak (along track x
    across track, ``dynamic_range`` dB shown), right the cuts through the peak along and across
    track with the -3 dB level, their widths and PSLR in the legend (`mitsonar.sas.psf`). Saved
    to ``path`` (.png, .pdf, .svg) when given; returns the Figure."""
    from matplotlib.figure import Figure

    from mitsonar.products.plots import _save
    from mitsonar.sas.quality import psf

    f = psf(image)
    g = image.grid
    db = image.power_db
    i, j = f["peak_index"]
    fig = Figure(figsize=figsize, dpi=dpi, layout="constrained")
    ax, cut = fig.subplots(1, 2, width_ratios=(1.0, 1.2))
    x_cm, y_cm = (g.x - g.x[i]) * 100, (g.y - g.y[j]) * 100
    mesh = ax.pcolormesh(y_cm, x_cm, db, vmin=-float(dynamic_range), vmax=0.0, cmap="viridis", shading="nearest")
    ax.set_aspect("equal")
    ax.set_xlabel("across track (cm)")
    ax.set_ylabel("along track (cm)")
    fig.colorbar(mesh, ax=ax, label="dB re peak", shrink=0.85)
    cut.plot(x_cm, db[:, j], label=f"along: {f['along'] * 100:.2f} cm, PSLR {f['pslr_along']:.1f} dB")
    cut.plot(y_cm, db[i, :], label=f"across: {f['across'] * 100:.2f} cm, PSLR {f['pslr_across']:.1f} dB")
    cut.axhline(-3.01, color="0.5", lw=0.8, ls="--")
    cut.set_ylim(-float(dynamic_range), 1.0)
    cut.set_xlabel("distance from the peak (cm)")
    cut.set_ylabel("dB re peak")
    cut.legend(loc="lower center", fontsize=7, frameon=False)
    if title:
        fig.suptitle(title, fontsize=9)
    _save(fig, path)
    return fig
