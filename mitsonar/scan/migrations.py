"""The migrations of old scan files: what a file's electronics settings meant when it was written,
in today's names and meaning. `mitsonar.scan.fileformat` applies them as it reads a file; the
receiver's `Electronics.from_dict` takes the renamed fields too.

These are facts about files already written, frozen here: they do not follow today's defaults
(`mitsonar.acoustics.levels`). This module imports nothing from mitsonar.
"""
from __future__ import annotations

import math

import numpy as np

#: The last release whose ``source_level`` was a calibration constant (CHANGELOG.md: the change to
#: dB re 1 uPa at 1 m came after it).
CALIBRATION_UNTIL = "0.2.0"
#: dB: a recorded ``source_level`` below this (the least source level a head may be given since
#: then) with no ``receiver_sensitivity`` is the calibration constant of those files.
CALIBRATION_BELOW = 150.0
#: dB re 1 uPa at 1 m: the source level such a file's settings take (the default source level of
#: the release that changed the meaning); the receiver sensitivity keeps their sum.
MIGRATED_SOURCE_LEVEL = 200.0

#: Electronics fields saved under an earlier name: old name -> today's. ``bandwidth`` (the receiver's
#: noise bandwidth) became ``receiver_bandwidth`` when the sensor's ``bandwidth`` came to mean the
#: transducer's band.
RENAMED_SETTINGS = {"bandwidth": "receiver_bandwidth"}


def rename_settings(settings: dict) -> dict:
    """``settings`` with the fields of `RENAMED_SETTINGS` under today's names (an old key is dropped
    when today's is also there)."""
    if not any(k in settings for k in RENAMED_SETTINGS):
        return settings
    out = {k: v for k, v in settings.items() if k not in RENAMED_SETTINGS}
    for old, new in RENAMED_SETTINGS.items():
        if old in settings and new not in settings:
            out[new] = settings[old]
    return out


def migrate_settings(settings: dict) -> dict:
    """Electronics settings recorded by mitsonar up to `CALIBRATION_UNTIL` (a scan file's), in today's
    meaning: a number ``source_level`` below `CALIBRATION_BELOW` with no ``receiver_sensitivity``
    was the calibration constant; it becomes `MIGRATED_SOURCE_LEVEL` plus the sensitivity that
    keeps the sum, so re-applying the electronics gives the same bytes; renamed fields take their
    new names (`rename_settings`). Others pass unchanged."""
    settings = rename_settings(settings)
    old = settings.get("source_level")
    if ("receiver_sensitivity" in settings or isinstance(old, bool)
            or not isinstance(old, (int, float, np.integer, np.floating)) or not math.isfinite(old)
            or old >= CALIBRATION_BELOW):
        return settings
    return {**settings, "source_level": MIGRATED_SOURCE_LEVEL,
            "receiver_sensitivity": float(old) - MIGRATED_SOURCE_LEVEL}
