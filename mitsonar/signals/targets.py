"""Point scatterers: isotropic, deterministic targets of a given target strength.

A `PointTarget` at ``x`` (world, m) of target strength ``TS`` (dB re 1 m^2, the backscattering
cross-section over 4 pi) answers a pulse from a transmitter at ``o`` with an echo of level

    EL = SL + 10 log10 B_tx(u) - 40 log10 r - 2 alpha r + TS          (r = |x - o|, u its direction)

at the transmitter (the sonar equation of a point target, Urick, *Principles of Underwater Sound*,
3rd ed., 1983, ch. 9; the same point-target level as ``Scan.echo_level``: ``SL - 40 log r - 2 alpha
r + TS`` on the axis). In the renderer's energy units (on-axis source intensity 1 W/sr) the echo
energy is ``E = B_tx(u) 10^(TS / 10) / r^4 10^(-alpha 2 r / 10)`` and the complex amplitude of
`mitsonar.signals.synthesis.synthesize` is ``sqrt(E)``, real and positive: the target scatters the
same in every direction and its phase is only the travel-time phase of each element
(``-2 pi f_c tau``), so two renders give the same waveform whatever the path or speckle seed (no
Monte-Carlo variance, unlike the scene's rough-surface scatterers; a sphere of the scene stays a
glint). With ``element_pattern='beam'`` the receive pattern multiplies ``E`` too.

Targets are calibration objects, for closed-form checks of beamformers and synthetic-aperture
processors (`mitsonar.sas`), summed coherently with the scene's echoes. They cast no shadow and
are seen without occlusion.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PointTarget:
    """An isotropic point scatterer (module docstring): ``position`` (3,) world m,
    ``target_strength`` dB re 1 m^2."""

    position: tuple
    target_strength: float = 0.0


def check_targets(targets, where="render_echoes") -> tuple[np.ndarray, np.ndarray]:
    """(positions (n, 3), target strengths (n,)) of ``targets``: a `PointTarget`, a list of them,
    or None (no targets); a ValueError naming ``targets`` in one line otherwise."""
    if targets is None:
        return np.zeros((0, 3)), np.zeros(0)
    items = [targets] if isinstance(targets, PointTarget) else targets
    allowed = "a PointTarget or a list of them, each with a finite (x, y, z) in m and a finite target_strength in dB"
    try:
        items = list(items)
    except TypeError:
        raise ValueError(f"{where} 'targets': {type(targets).__name__} is not allowed ({allowed})") from None
    pos, ts = [], []
    for i, t in enumerate(items):
        if not isinstance(t, PointTarget):
            raise ValueError(f"{where} 'targets'[{i}]: {type(t).__name__} is not allowed ({allowed})")
        try:
            p = np.asarray(t.position, dtype=np.float64)
            s = float(t.target_strength)
        except (TypeError, ValueError):
            p, s = np.full(1, np.nan), math.nan
        if p.shape != (3,) or not np.isfinite(p).all() or not math.isfinite(s) or isinstance(t.target_strength, bool):
            raise ValueError(f"{where} 'targets'[{i}]: {t!r} is not allowed ({allowed})")
        pos.append(p)
        ts.append(s)
    return np.array(pos).reshape(-1, 3), np.array(ts)


def target_scatterers(positions, strengths, pose, beam_gain, absorption, two_way=False):
    """(amplitudes (n,), positions (n, 3), outbound lengths (n,)) of the targets for one row whose
    beam frame is ``pose`` (4x4): amplitudes ``sqrt(E)`` of the module docstring, ``beam_gain`` a
    function of (n, 3) unit directions in the beam frame giving ``B_tx``; ``two_way`` squares it
    (the transducer as its own receiver)."""
    x = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    o = pose[:3, 3]
    d = x - o
    r = np.maximum(np.linalg.norm(d, axis=1), 1e-9)
    local = (d / r[:, None]) @ pose[:3, :3]
    b = np.asarray(beam_gain(local), dtype=np.float64).reshape(-1) if len(x) else np.zeros(0)
    if two_way:
        b = b * b
    energy = b * 10.0 ** (np.asarray(strengths, dtype=np.float64) / 10.0) / r ** 4 \
        * 10.0 ** (-float(absorption) * 2.0 * r / 10.0)
    return np.sqrt(energy).astype(np.complex128), x, r
