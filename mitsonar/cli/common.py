"""What every ``mitsonar`` subcommand shares: the policy for outputs that exist, the checks of the
count flags (``--spp``, ``--seed``, ``--max-scans``, ``--max-depth``) in the flags' own words, and
``--sensor``. Imports no command module, so each of them may use it.

Existing outputs (docs/howto/command_line.rst, "Existing outputs"): every option that names
something a command writes is added with `add_output`, and `check_outputs` (run by ``mitsonar``'s
main on the parsed arguments, before the command starts) refuses one that would overwrite an
existing file unless ``--force``, in one line: ``-o out.png: exists; --force to overwrite``.
Folders that a command resumes or caches into (``dataset -o``, ``compare -o``) are added with
``reused=True`` and never refused.
"""
from __future__ import annotations

import os
import re

FORCE_HELP = "overwrite existing outputs"


def add_force(parser, help=FORCE_HELP):
    """``--force``: overwrite existing outputs (the policy above)."""
    parser.add_argument("--force", action="store_true", help=help)


def existing_file(path, args) -> list:
    """What writing the file ``path`` overwrites: ``[path]`` if a file (not a folder) is there."""
    return [path] if os.path.lexists(path) and not os.path.isdir(path) else []


def files_in_folder(names=(), pattern=None):
    """An ``existing`` for `add_output` of an output folder: the files in it named in ``names``
    or matching the regular expression ``pattern`` (the files the command writes there), sorted."""
    match = re.compile(pattern).fullmatch if pattern else (lambda name: False)

    def existing(folder, args) -> list:
        if not os.path.isdir(folder):
            return []
        return sorted(f for f in os.listdir(folder) if f in names or match(f))
    return existing


def add_output(parser, *flags, existing=existing_file, reused=False, **kwargs):
    """Add an option (``add_argument(*flags, **kwargs)``) naming something the command writes, under
    the ``--force`` policy (module doc; the parser needs `add_force`): `check_outputs` refuses it
    when ``existing(path, args)`` lists files it would overwrite. ``existing``: `existing_file`
    (default) or `files_in_folder` (an output folder), or any function of (path, args) listing
    them. ``reused``: a folder the command resumes or caches into on purpose, never refused.
    Returns the argparse action."""
    action = parser.add_argument(*flags, **kwargs)
    action.existing = None if reused else existing
    parser.set_defaults(outputs_=(*(parser.get_default("outputs_") or ()), action))
    return action


def overwrite_refusal(action, path, found) -> str:
    """The one line of `check_outputs`: the flag, the output, what exists, ``--force to overwrite``."""
    flag = action.option_strings[0] if action.option_strings else action.dest.upper()
    path = os.fspath(path)
    if found == [path]:
        return f"{flag} {path}: exists; --force to overwrite"
    more = f" and {len(found) - 1} more of its outputs" if len(found) > 1 else ""
    return f"{flag} {path}: already holds {found[0]}{more}; --force to overwrite"


def check_outputs(args, error=ValueError) -> None:
    """Refuse, raised as ``error`` in one line (`overwrite_refusal`), the first output of ``args``
    (those added with `add_output`) that would overwrite existing files, unless ``--force``.
    Looks at the file system only: run it before any work."""
    if getattr(args, "force", False):
        return
    for action in getattr(args, "outputs_", ()):
        path = getattr(args, action.dest, None)
        if path is None or action.existing is None:
            continue
        found = action.existing(os.fspath(path), args)
        if found:
            raise error(overwrite_refusal(action, path, found))


def _max_depth():
    from mitsonar.sim.variant import ensure_variant

    ensure_variant()
    from mitsonar.plugins.integrators.common import MAX_DEPTH

    return MAX_DEPTH


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
