"""Ray diagram of a sound-speed profile, as survey software draws it: the profile (sound speed
against depth) beside the rays of a multibeam fan traced through it (depth against across-track
distance), depth increasing downward on both.

    from mitsonar.acoustics import SoundSpeedProfile
    from mitsonar.products.raydiagram import ray_diagram
    svp = SoundSpeedProfile.from_csv("svp.csv")
    ray_diagram(svp, head_depth=2.0, seabed_depth=40.0, nominal_speed=1500.0, path="rays.png")

With ``nominal_speed`` the diagram also draws, dashed, the straight beams a processing that
ignores the profile would assume, and marks (x) where it would put each sounding: the refraction
error (`SoundSpeedProfile.locate` against a straight line for the same travel time).
"""
from __future__ import annotations

import math

import numpy as np

from mitsonar.acoustics.profile import ProfileError, SoundSpeedProfile

__all__ = ["ray_diagram"]


def ray_diagram(profile, *, head_depth=0.0, seabed_depth=None, angles=tuple(range(-60, 61, 10)),
                travel_time=None, nominal_speed=None, path=None, title=None):
    """Draw ``profile`` (a `SoundSpeedProfile`) and the rays of a fan launched from ``head_depth``
    (m) at the beam ``angles`` (deg from the vertical, positive to port; drawn against the signed
    across-track distance, port positive), each traced until it reaches ``seabed_depth``
    (m, drawn as a line) or after the one-way ``travel_time`` (s); at least one of the two.
    ``nominal_speed`` (m/s): also the straight beams at that speed for the same travel times, and
    where they put each sounding. Returns the matplotlib Figure; writes it to ``path`` (png, pdf,
    svg) when given (under a temporary name, renamed at the end)."""
    from matplotlib import colormaps
    from matplotlib.figure import Figure

    if not isinstance(profile, SoundSpeedProfile):
        raise ProfileError(f"ray_diagram: profile {profile!r} is not a SoundSpeedProfile")
    if seabed_depth is None and travel_time is None:
        raise ProfileError("ray_diagram: give seabed_depth (m) or travel_time (s): where the rays stop")
    if seabed_depth is not None and not (math.isfinite(seabed_depth) and seabed_depth > head_depth):
        raise ProfileError(f"ray_diagram: seabed_depth {seabed_depth!r} is not allowed (a depth below the head's "
                           f"{head_depth:g} m)")
    angles = np.asarray(angles, dtype=float).ravel()
    if angles.size == 0 or not np.all(np.isfinite(angles)) or np.any(np.abs(angles) > 90):
        raise ProfileError(f"ray_diagram: angles {angles.tolist()!r} is not allowed (beam angles from the vertical, "
                           "-90 to 90 deg)")
    if nominal_speed is not None and not (math.isfinite(nominal_speed) and nominal_speed > 0):
        raise ProfileError(f"ray_diagram: nominal_speed {nominal_speed!r} is not allowed (a speed > 0 m/s)")
    cap = travel_time
    if cap is None:   # long enough for any ray to reach the seabed unless it turns above it
        cap = 20.0 * (seabed_depth - head_depth) / float(profile.speeds.min())

    fig = Figure(figsize=(11.0, 5.5), dpi=120)
    ax, bx = fig.subplots(1, 2, sharey=True, gridspec_kw=dict(width_ratios=(1, 3)))
    colours = colormaps["coolwarm"]
    depth_max = seabed_depth if seabed_depth is not None else head_depth
    ends = []
    for k, b in enumerate(angles):
        th = math.pi / 2 - math.radians(abs(b))
        ray = profile.trace(head_depth, th, travel_time=cap, to_depth=seabed_depth, samples=24)
        side = 1.0 if b >= 0 else -1.0
        colour = colours(0.5 + 0.5 * b / max(1e-9, np.abs(angles).max()))
        bx.plot(side * ray.x, ray.depth, "-", color=colour, lw=1.2, label=None)
        depth_max = max(depth_max, float(ray.depth.max()))
        ends.append((side, ray, b, colour))
    if nominal_speed is not None:
        for i, (side, ray, b, colour) in enumerate(ends):
            r = nominal_speed * ray.time[-1]
            a = math.radians(abs(b))
            bx.plot([0.0, side * r * math.sin(a)], [head_depth, head_depth + r * math.cos(a)], "--", color="0.55",
                    lw=0.8, label=f"straight at {nominal_speed:g} m/s" if i == 0 else None)
            bx.plot(side * r * math.sin(a), head_depth + r * math.cos(a), "x", color=colour, ms=6,
                    label="sounding without the profile" if i == 0 else None)
            depth_max = max(depth_max, head_depth + r * math.cos(a))
    bx.plot([s * ray.x[-1] for s, ray, _, _ in ends], [ray.depth[-1] for _, ray, _, _ in ends], "o", color="k",
            ms=3, label="ray end (true position)")
    if seabed_depth is not None:
        bx.axhline(seabed_depth, color="saddlebrown", lw=1.5, label=f"seabed, {seabed_depth:g} m")
    bx.plot([0.0], [head_depth], "kv", ms=8, label=f"transducer, {head_depth:g} m")
    bx.set(xlabel="across-track distance [m] (port +)",
           title=title or (f"rays of the fan, {angles.min():g} to {angles.max():g} deg" +
                           (f", {travel_time * 1e3:g} ms one way" if travel_time is not None else "")))
    bx.grid(True, alpha=0.3)
    bx.legend(fontsize=8, loc="lower center")
    z = np.linspace(0.0, max(depth_max, float(profile.depths[-1])) * 1.05, 400)
    ax.plot(profile.speed(z), z, "-", color="C0", lw=1.5)
    ax.plot(profile.speeds, profile.depths, "o", color="C0", ms=3, label="samples")
    ax.axhline(head_depth, color="k", lw=0.6, ls=":")
    if seabed_depth is not None:
        ax.axhline(seabed_depth, color="saddlebrown", lw=1.5)
    ax.set(xlabel="sound speed [m/s]", ylabel="depth [m] (down)", title="sound-speed profile")
    ax.grid(True, alpha=0.3)
    lo, hi = float(profile.speeds.min()), float(profile.speeds.max())
    pad = max(1.0, 0.15 * (hi - lo))
    ax.set_xlim(lo - pad, hi + pad)
    ax.set_ylim(z[-1], min(0.0, head_depth))        # depth increasing downward
    fig.tight_layout()
    if path is not None:
        from mitsonar.products.plots import _save

        _save(fig, path)
    return fig
