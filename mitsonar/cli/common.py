"""What every ``mitsonar`` subcommand shares: the policy for outputs that exist, the checks of the
count flags (``--spp``, ``--seed``, ``--max-scans``, ``--max-depth``) in the flags' own words, and
``--sensor``. Imports no command module, so each of them may use it.

Existing outputs (README, "Existing outputs"): a command that writes a file refuses one that
exists unless ``--force``. Commands that overwrote silently before (``render``, ``plot``,
``demo``, ``record``, ``replay``, ``map``) still overwrite for one release, with one warning line
(`warn_overwrite`); ``survey``, ``bathymetry`` and ``export`` refuse already. Folders that a
command resumes or caches into (``dataset``, ``compare``'s cached reference) keep doing so.
"""
from __future__ import annotations

import os
import warnings

FORCE_HELP = "overwrite existing outputs"


def add_force(parser, help=FORCE_HELP):
    """``--force``: overwrite existing outputs (the policy above)."""
    parser.add_argument("--force", action="store_true", help=help)


def warn_overwrite(paths, force) -> None:
    """One warning line for the outputs among ``paths`` that exist, unless ``force``: they are
    overwritten this release; from the next one the command will refuse them without ``--force``."""
    existing = [os.fspath(p) for p in paths if p and os.path.exists(p)]
    if existing and not force:
        what = (existing[0] if len(existing) == 1 else " and ".join(existing) if len(existing) == 2
                else f"{existing[0]} and {len(existing) - 1} more outputs")
        verb = "exists" if len(existing) == 1 else "exist"
        warnings.warn(f"{what} {verb}; overwriting; from the next release this needs --force", FutureWarning,
                      stacklevel=2)


def _max_depth():
    from mitsonar.plugins import module

    return module("common").MAX_DEPTH


def check_counts(args, error) -> None:
    """Refuse, with one line raised as ``error`` naming the flag, a count flag of ``args`` out of its
    range (the limits `render_scan` and `render_survey` hold), before any work."""
    from mitsonar._checks import is_whole
    from mitsonar.sim.render import SEED_ALLOWED, SEED_MAX, SPP_ALLOWED, SPP_MAX
    from mitsonar.sim.survey import MAX_SCANS, MAX_SCANS_ALLOWED

    for dest, lo, hi, allowed in (("spp", 1, SPP_MAX, SPP_ALLOWED), ("seed", 0, SEED_MAX, SEED_ALLOWED),
                                  ("max_scans", 1, MAX_SCANS, MAX_SCANS_ALLOWED), ("max_depth", 1, None, None)):
        value = getattr(args, dest, None)
        if value is None:
            continue
        if dest == "max_depth":
            hi = _max_depth()
            allowed = f"a whole number of surface bounces from 1 to {hi}"
        if not (is_whole(value) and lo <= value <= hi):
            raise error(f"--{dest.replace('_', '-')} {value}: not allowed ({allowed})")


def add_sensor(parser):
    """``--sensor ID|INDEX``: which of the scene's sensors renders."""
    parser.add_argument("--sensor", metavar="ID|INDEX",
                        help="the scene's sensor to render: its XML id or its index (default: the first sonar "
                             "sensor; a scene with several warns once)")


def sensor_of(scene, args, error=None):
    """The sensor object ``--sensor`` names (`mitsonar.sim.render.pick_sensor`), or the first sonar
    sensor with at most one warning; ``error`` (a class) re-raises the refusal as that type."""
    from mitsonar.sim.render import pick_sensor
    from mitsonar.sim.scene import SceneError

    try:
        return pick_sensor(scene, getattr(args, "sensor", None))
    except SceneError as exc:
        if error is None:
            raise
        raise error(str(exc)) from None
