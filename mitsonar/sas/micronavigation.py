"""DPCA micronavigation: the platform's sway estimated from the redundant phase centres.

When the platform advances ``k D / 2`` per ping (``k < N``, a whole number), the last ``N - k``
phase centres of ping ``r`` (the transmitter-receiver midpoints, `mitsonar.sas.config`) fall on the
first ``N - k`` of ping ``r + 1``: the two pairs see the seabed from the same point, so their echoes
are the same up to the displacement of the platform between the pings along the line of sight.
The phase of their zero-lag cross-correlation over a block of range ``b``,

    phi_b = arg sum_{k in b} y_{r+1, j}(k) y*_{r, j + k_adv}(k),   delta_b = phi_b lambda / (4 pi)

is the line-of-sight displacement there (two-way: ``4 pi / lambda`` per metre), less what the
navigation already predicts (the two pairs' bistatic baselines differ, and the receivers move
during the flight: the predicted path difference of a seabed point at each block's range takes
both in); a horizontal sway ``delta_y`` gives ``delta_b = delta_y g_b / R_b``
(``g_b`` the ground range, ``R_b`` the slant range of the block, on a flat seabed at ``seabed_z``),
so ``delta_y`` is the weighted least-squares fit over the blocks and overlapping pairs (weights
``|sum y y*|``), summed from ping to ping into a sway track (Bellettini and Pinto, "Theoretical
accuracy of synthetic aperture sonar micronavigation using a displaced phase-center antenna", IEEE
J. Oceanic Eng. 27(4), 2002, sections II-III: the DPCA estimate of the inter-ping displacement
from the coherence of the overlapping phase centres; Hayes and Gough 2009, section on motion
estimation). Only sway is estimated (not surge, heave or yaw); the first ping's sway is taken
as the navigation's (an offset of the whole image, no defocus); each inter-ping sway must stay
under ``lambda / 4`` along the line of sight (the phase is not unwrapped).
"""
from __future__ import annotations

import numpy as np


def micronavigation(echoes, navigation=None, *, seabed_z=0.0, block=32, min_range=None):
    """A `mitsonar.Trajectory`: ``navigation`` (default the track of the rendered poses, which
    needs the echoes' ``meta['mounts']``) with each ping's sway replaced by the DPCA estimate
    (module docstring). ``block`` samples of compressed data per range block; ``min_range`` m, the
    nearest slant range used (default 1.2 times the altitude over ``seabed_z``). Raises a
    ValueError naming the argument when the pings share no phase centres."""
    from mitsonar.geometry.trajectory import Trajectory
    from mitsonar.sas.backprojection import row_geometry
    from mitsonar.signals.processing import matched_filter

    meta = echoes.meta
    if "mounts" not in meta:
        raise ValueError("micronavigation 'echoes': not allowed without a trajectory (render them with one)")
    e = np.asarray(echoes.elements, dtype=np.float64)
    poses, vel = row_geometry(echoes, navigation)
    n_rows = len(poses)
    if n_rows < 2:
        raise ValueError("micronavigation 'echoes': at least two pings are needed")
    order = np.argsort(e[:, 0])
    spacing = float(np.median(np.diff(e[order, 0])))
    adv = np.einsum("ri,ri->r", poses[1:, :3, 3] - poses[:-1, :3, 3], poses[:-1, :3, 0])
    steps = 2.0 * adv / spacing
    k_signed = int(round(float(np.median(steps))))
    k_adv = abs(k_signed)           # a starboard channel's beam frame x points aft: the advance is negative
    n_el = len(e)
    if not 1 <= k_adv < n_el or np.max(np.abs(steps - k_signed)) > 0.15:
        raise ValueError(f"micronavigation 'echoes': pings advancing {float(np.median(adv)):.4g} m with receivers "
                         f"{spacing:.4g} m apart are not allowed (a whole number k of half receivers per ping, "
                         f"1 <= k < {n_el}, so phase centres overlap)")
    fs, c, lam = echoes.sample_rate, echoes.sound_speed, echoes.wavelength
    y = np.stack([matched_filter(echoes.signal[r], echoes.pulse, fs) for r in range(n_rows)])
    n = echoes.n_samples
    nb = n // int(block)
    t_mid = (np.arange(nb) + 0.5) * block / fs
    slant = 0.5 * c * t_mid
    sway = np.zeros(n_rows)
    for r in range(n_rows - 1):
        h = poses[r, 2, 3] - float(seabed_z)
        r_min = 1.2 * abs(h) if min_range is None else float(min_range)
        ok = slant > max(r_min, abs(h) * 1.0001)
        g = np.sqrt(np.maximum(slant ** 2 - h * h, 0.0))
        rows_a, rows_b = [], []
        for j in range(n_el - k_adv):
            # ping r+1's receiver a over ping r's receiver b: x_b - x_a = 2 x advance
            a, b = (order[j], order[j + k_adv]) if k_signed > 0 else (order[j + k_adv], order[j])
            cross = (y[r + 1, a] * np.conj(y[r, b]))[:nb * block].reshape(nb, block).sum(axis=1)
            # what the navigation predicts for a seabed point at each block's range, straight to port
            across = _across(poses[r])
            mid = 0.5 * (poses[r, :3, 3] + poses[r + 1, :3, 3])
            pts = mid[None, :] + g[:, None] * across[None, :]
            pts[:, 2] = float(seabed_z)
            # the receiver hears the block after the two-way flight, moved by v 2 R / c (which changes
            # the two pairs' bistatic terms unequally: their baselines differ)
            path = lambda rr, el: (np.linalg.norm(pts - poses[rr, :3, 3], axis=1)  # noqa: E731
                                   + np.linalg.norm(pts - (poses[rr, :3, :3] @ e[el] + poses[rr, :3, 3])
                                                    - vel[rr] * (2.0 * slant / c)[:, None], axis=1))
            predicted = path(r + 1, a) - path(r, b)
            phase = np.angle(cross * np.exp(2j * np.pi * predicted / lam))
            # the echo of ping r+1 arrives later by delta (path longer) -> phase -4 pi delta / lambda
            delta = -phase * lam / (4.0 * np.pi)
            w = np.abs(cross) * ok
            rows_a.append(w * g / np.maximum(slant, 1e-9))
            rows_b.append(w * delta)
        A, B = np.concatenate(rows_a), np.concatenate(rows_b)
        den = float(A @ A)
        # a sway towards the seabed (+ across) shortens the path: delta = -dy g / R
        sway[r + 1] = sway[r] - (float(A @ B) / den if den > 0 else 0.0)
    t = meta["start_time"] + echoes.times
    vehicle = poses @ np.linalg.inv(meta["mounts"])
    vehicle[:, :3, 3] += sway[:, None] * np.stack([_across(p) for p in poses])
    return Trajectory(t, vehicle, _source="micronavigation")


def _across(pose):
    """Unit horizontal vector of a row's boresight: the across-track direction it looks towards."""
    b = np.array([pose[0, 2], pose[1, 2], 0.0])
    return b / max(float(np.linalg.norm(b)), 1e-12)
