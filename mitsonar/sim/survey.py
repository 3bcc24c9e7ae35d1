"""`render_survey`: consecutive scans along a vehicle's whole track, streamed to disk.

A survey is the scans a head takes one after another while the vehicle follows its trajectory:
scan ``i`` starts at ``t_0 + i * scan_period`` (``scan_period``: ``n_pings * ping_period`` for a
mechanical head, a full sweep; ``ping_period`` for a multibeam head, one frame), and the survey
holds every scan whose pings all fit in the trajectory (or in ``[start_time, end_time]``). Each
scan is one `render_scan` (one wavefront of all its pings) with its own seed, derived from the
survey's seed and the scan's index, so the same seed gives the same survey bit for bit and no two
scans share their paths.
"""
from __future__ import annotations

import math
import os
import sys

import numpy as np

from mitsonar.sim.render import (SEED_ALLOWED, SEED_MAX, SPP_ALLOWED, SPP_MAX, _integrator, _whole, moving_head_poses, pick_sensor,
                     render_scan)
from mitsonar.sim.scene import SceneError, sonar_of
from mitsonar.geometry.trajectory import Trajectory

SCAN_NAME = "scan_{:05d}{}"
MAX_SCANS = 10 ** 9
MAX_SCANS_ALLOWED = f"a whole number of scans from 1 to {MAX_SCANS}"
TRAJECTORY_NAME = "trajectory.tum"


def scan_seed(seed: int, index: int) -> int:
    """The path seed of scan ``index`` of a survey seeded ``seed`` (NumPy's SeedSequence hash of
    both, so consecutive scans and consecutive survey seeds give unrelated paths)."""
    return int(np.random.SeedSequence([int(seed), int(index)]).generate_state(1)[0])


def survey_plan(sonar, trajectory, start_time=None, end_time=None, max_scans=None):
    """Start times (s, on the trajectory's clock) of the survey's scans; a plan with no scan is
    refused with one sentence naming the scan's duration and the time available."""
    lo, hi = trajectory.span
    t0 = lo if start_time is None else float(start_time)
    t1 = hi if end_time is None else float(end_time)
    for name, v in (("start_time", t0), ("end_time", t1)):
        if not (math.isfinite(v) and lo <= v <= hi):
            raise SceneError(f"render_survey '{name}': {v!r} is not allowed (a time within the trajectory's "
                             f"span [{lo:.9g}, {hi:.9g}] s)")
    last_ping = float(sonar.ping_times()[-1])
    if t1 - t0 < last_ping:
        raise SceneError(f"render_survey: one scan takes {last_ping:.6g} s from its first ping to its last "
                         f"({sonar.n_pings} pings, ping_period {sonar.ping_period:.6g} s); the trajectory gives "
                         f"{t1 - t0:.6g} s ([{t0:.9g}, {t1:.9g}] s)")
    n = int(math.floor((t1 - t0 - last_ping) / sonar.scan_period + 1e-9)) + 1
    if max_scans is not None:
        n = min(n, max_scans)
    return t0 + np.arange(n) * sonar.scan_period


def render_survey(scene, trajectory, output=None, *, spp=1024, seed=0, start_time=None, end_time=None,
                  max_scans=None, sensor=0, integrator=None, max_depth=None, electronics=None, ext=".npz",
                  progress=True, sound_speed_profile=None, meta=None):
    """Render the scans of a survey along ``trajectory``, one after another; returns an iterator
    of `Scan`, each saved before it is yielded when ``output`` is given.

    ============== ==============================================================================
    scene          a scene with a ``sonar`` sensor whose ``to_world`` is the mount on the vehicle
    trajectory     the vehicle's `Trajectory` (x forward, y port, z up)
    output         folder (created) for ``scan_00000.npz``, ``scan_00001.npz``, ... and
                   ``trajectory.tum``; None: nothing is written
    spp, seed      paths per row and the survey's seed (scan i uses `scan_seed` (seed, i))
    start_time     first scan's start, s on the trajectory's clock (default: its first time)
    end_time       no ping after this time (default: the trajectory's last time)
    max_scans      at most this many scans (default: all that fit)
    ext            ``.npz`` or ``.exr``
    progress       True: a progress bar in pings on stderr; a callable ``progress(done, total)``
                   (pings); False or None: silent
    meta           more metadata for every scan (e.g. a `GeoFrame`'s ``origin`` and ``crs``)
    others         as in `render_scan`
    ============== ==============================================================================

    Every argument is checked before the first render. Each file is written under a temporary
    name and renamed, so a survey stopped (Ctrl-C) keeps every scan written so far, each
    readable, and no partial file. Only one scan is in memory at a time.
    """
    if not isinstance(trajectory, Trajectory):
        raise SceneError(f"render_survey 'trajectory': expected a mitsonar.Trajectory, got {type(trajectory).__name__}")
    spp = _whole("spp", spp, 1, SPP_MAX, SPP_ALLOWED, "render_survey")
    seed = _whole("seed", seed, 0, SEED_MAX, SEED_ALLOWED, "render_survey")
    if max_scans is not None:
        max_scans = _whole("max_scans", max_scans, 1, MAX_SCANS, MAX_SCANS_ALLOWED, "render_survey")
    if ext not in (".npz", ".exr"):
        raise SceneError(f"render_survey 'ext': {ext!r} is not allowed (.npz or .exr)")
    if isinstance(sensor, str):
        sensor = pick_sensor(scene, sensor, "render_survey 'sensor':")
    sonar = sonar_of(scene, sensor)
    starts = survey_plan(sonar, trajectory, start_time, end_time, max_scans)
    moving_head_poses(sonar, trajectory, starts[-1])     # the last scan fits (refused here if not)
    integrator = _integrator(scene, integrator)
    if sound_speed_profile is not None and not getattr(integrator, "REFRACTS", False):
        raise SceneError(f"render_survey 'sound_speed_profile': refracted paths are traced by the sonar_tof "
                         f"integrator only, not {type(integrator).__name__}")
    if output is not None:
        output = os.fspath(output)
        os.makedirs(output, exist_ok=True)
    return _scans(scene, trajectory, output, starts, sonar, dict(
        spp=spp, sensor=sensor, integrator=integrator, max_depth=max_depth, electronics=electronics,
        sound_speed_profile=sound_speed_profile),
        seed, ext, progress, dict(meta or {}))


def _scans(scene, trajectory, output, starts, sonar, kwargs, seed, ext, progress, meta=None):
    bar = None
    total = len(starts) * sonar.n_pings
    if progress is True:
        from tqdm import tqdm

        bar = tqdm(total=total, unit="ping", desc="survey", leave=False, file=sys.stderr, delay=0.5)
        progress = lambda done, _total: bar.update(done - bar.n)  # noqa: E731
    try:
        if output is not None:
            trajectory.to_tum(os.path.join(output, TRAJECTORY_NAME))
        for i, t in enumerate(starts):
            scan = render_scan(scene, seed=scan_seed(seed, i), trajectory=trajectory, start_time=float(t), **kwargs)
            scan.meta = scan.meta.replace(survey_index=i, survey_seed=seed, **(meta or {}))
            if output is not None:
                scan.save(os.path.join(output, SCAN_NAME.format(i, ext)))
            if progress:
                progress((i + 1) * sonar.n_pings, total)
            yield scan
    finally:
        if bar is not None:
            bar.close()


def survey_files(folder, ext=".npz") -> list:
    """The scan files of a survey folder, in order (``scan_00000``, ``scan_00001``, ...)."""
    names = sorted(f for f in os.listdir(folder) if f.startswith("scan_") and f.endswith(ext))
    return [os.path.join(folder, f) for f in names]
