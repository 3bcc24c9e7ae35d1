"""The sonar-equation report of a head in a scene: why an echo is, or is not, above the noise.

`sonar_equation_report` renders a scene (or takes a scan) and lists the terms of the active sonar
equation (Urick 1983, eqs. 2.1, 2.2) in dB: the head's source level SL, noise spectrum level NL,
receiver bandwidth B and directivity index DI, the noise in band ``NL + 10 log10 B - DI``; per ping the
strongest echo's range r, its echo level EL (`scan_echo_level`), the two-way transmission loss
``TL = 40 log10 r + 2 alpha r``, the target term it implies (``TS`` of a point target, or
``S_b + 10 log10 A`` of a seabed patch: ``EL - SL + TL``) and the SNR. `plot_levels` draws echo
level and noise against range. Command line:
``mitsonar levels SCENE.xml [-o fig.png]`` (`mitsonar.cli.levels`).
"""
from __future__ import annotations

import dataclasses
import math
import os

import numpy as np

from mitsonar.acoustics.levels import two_way_transmission_loss
from mitsonar.sonar_equation.scan_levels import receiver_of, scan_levels

#: Echoes nearer than this are left out of "the strongest echo" (TL -> -inf at r -> 0).
MIN_RANGE = 0.05


@dataclasses.dataclass
class SonarEquationReport:
    """The terms of the sonar equation for one scan (dB; ranges in m). ``pings`` holds one dict
    per ping: ``ping``, ``bearing`` (deg), ``range`` (the strongest echo's bin centre, NaN without
    echo), ``echo_level``, ``transmission_loss`` (two-way, `two_way_transmission_loss`), ``target``
    (``EL - SL + TL``: TS, or S_b + 10 log A)
    and ``snr``."""

    source_level: float
    noise_level: float
    receiver_bandwidth: float
    directivity_index: float
    noise_band_level: float
    absorption: float
    ranges: np.ndarray
    echo_level: np.ndarray
    pings: list

    def table(self, rows: int = 20) -> str:
        """The report as text: the head's terms, then up to ``rows`` pings (evenly spaced; 0: all)
        with their strongest echo."""
        head = [f"source level        SL  {self.source_level:8.1f} dB re 1 uPa at 1 m",
                f"noise level         NL  {self.noise_level:8.1f} dB re 1 uPa^2/Hz",
                f"receiver bandwidth  B   {self.receiver_bandwidth:8.0f} Hz  (10 log B = "
                f"{10 * math.log10(self.receiver_bandwidth):.1f} dB)",
                f"directivity index   DI  {self.directivity_index:8.1f} dB",
                f"noise in band  NL + 10 log B - DI = {self.noise_band_level:.1f} dB re 1 uPa",
                f"absorption          alpha {self.absorption:g} dB/m;  TL = 40 log r + 2 alpha r (two-way)",
                "",
                f"{'ping':>5} {'bearing':>8} {'r (m)':>7} {'EL':>7} {'TL':>7} {'TS|Sb+10logA':>13} {'SNR':>7}"]
        pick = self.pings
        if rows and len(pick) > rows:
            pick = [pick[i] for i in np.linspace(0, len(pick) - 1, rows).round().astype(int)]
        for p in pick:
            if not math.isfinite(p["range"]):
                head.append(f"{p['ping']:5d} {p['bearing']:8.1f} {'no echo':>7}")
                continue
            head.append(f"{p['ping']:5d} {p['bearing']:8.1f} {p['range']:7.2f} {p['echo_level']:7.1f} "
                        f"{p['transmission_loss']:7.1f} {p['target']:13.1f} {p['snr']:7.1f}")
        head.append("EL = SL - TL + (TS | S_b + 10 log A);  SNR = EL - (NL + 10 log B - DI);  "
                    "EL, SNR of the strongest bin beyond "
                    f"{MIN_RANGE:g} m")
        return "\n".join(head)

    def __str__(self) -> str:
        return self.table()


def sonar_equation_report(scene_or_scan, *, spp: int = 256, seed: int = 0, sensor=0, **render_kw) -> SonarEquationReport:
    """The sonar equation for a head in a scene (rendered with ``spp`` paths per ping, `render_scan`'s
    ``sensor`` and other keywords) or for a `Scan` (or a scan file's path: ``.exr``/``.npz``; a
    scene XML path is loaded)."""
    scan = _scan_of(scene_or_scan, spp, seed, sensor, render_kw)
    e = receiver_of(scan)
    levels = scan_levels(scan)
    el, noise = levels.echo_level, levels.noise_band_level
    ranges = np.asarray(scan.ranges, dtype=np.float64)
    usable = ranges >= MIN_RANGE
    pings = []
    bearings = np.degrees(scan.bearings)
    for k in range(scan.n_pings):
        row = np.where(usable, el[k].astype(np.float64), -np.inf)
        j = int(np.argmax(row))
        if not np.isfinite(row[j]):
            pings.append(dict(ping=k, bearing=float(bearings[k]), range=math.nan, echo_level=-math.inf,
                              transmission_loss=math.nan, target=math.nan, snr=-math.inf))
            continue
        tl = float(two_way_transmission_loss(ranges[j], scan.absorption))
        pings.append(dict(ping=k, bearing=float(bearings[k]), range=float(ranges[j]), echo_level=float(row[j]),
                          transmission_loss=tl, target=float(row[j] - e.source_level + tl),
                          snr=float(row[j] - noise)))
    return SonarEquationReport(source_level=e.source_level, noise_level=e.noise_level,
                               receiver_bandwidth=e.noise_bandwidth(scan.bin_width, scan.sound_speed),
                               directivity_index=levels.directivity_index, noise_band_level=noise,
                               absorption=scan.absorption, ranges=ranges, echo_level=el, pings=pings)


def _scan_of(obj, spp, seed, sensor, render_kw):
    from mitsonar.scan import Scan
    from mitsonar.scan.io import load_scan

    if isinstance(obj, Scan):
        return obj
    if isinstance(obj, (str, os.PathLike)):
        path = os.fspath(obj)
        if os.path.splitext(path)[1].lower() in (".exr", ".npz"):
            return load_scan(path)
        from mitsonar.sim.scene import load_scene

        obj = load_scene(path)
    from mitsonar.sim.render import render_scan

    return render_scan(obj, spp=spp, seed=seed, sensor=sensor, **render_kw)


def plot_levels(report: SonarEquationReport, path=None, ping=None):
    """Echo level against range (the ping with the strongest echo, or ``ping``; and the largest
    over all pings) and the noise in band as a horizontal line; axes in m and dB re 1 uPa.
    Written to ``path`` (``.png``/``.pdf``/``.svg``) when given; returns the matplotlib Figure."""
    from matplotlib.figure import Figure

    from mitsonar.products.plots import _save

    el = np.asarray(report.echo_level, dtype=np.float64)
    if ping is None:
        ping = int(np.argmax([p["echo_level"] for p in report.pings]))
    if not 0 <= ping < el.shape[0]:
        raise ValueError(f"plot_levels: ping {ping} is not in 0..{el.shape[0] - 1}")
    fig = Figure(figsize=(7, 4), dpi=120)
    ax = fig.add_subplot()
    finite = el[np.isfinite(el)]
    floor = min(report.noise_band_level, finite.max() if finite.size else report.noise_band_level) - 40.0
    show = lambda a: np.where(np.isfinite(a), a, np.nan)  # noqa: E731  (-inf: no echo, a gap)
    ax.plot(report.ranges, show(el.max(axis=0)), color="0.7", lw=1, label="echo level, largest over pings")
    ax.plot(report.ranges, show(el[ping]), color="C0", lw=1.2,
            label=f"echo level, ping {ping} ({report.pings[ping]['bearing']:.1f} deg)")
    ax.axhline(report.noise_band_level, color="C3", ls="--",
               label=f"noise NL + 10 log B - DI = {report.noise_band_level:.1f} dB")
    ax.set_xlabel("range (m)")
    ax.set_ylabel("level (dB re 1 uPa)")
    top = max(report.noise_band_level, finite.max() if finite.size else report.noise_band_level) + 10.0
    ax.set_ylim(min(report.noise_band_level - 10.0, max(floor, top - 100.0)), top)   # the noise line in view
    ax.set_title(f"Sonar equation: SL {report.source_level:.0f} dB, DI {report.directivity_index:.1f} dB")
    ax.legend(loc="upper right", fontsize=8)
    ax.grid(alpha=0.3)
    _save(fig, path)
    return fig
