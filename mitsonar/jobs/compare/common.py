"""What every part of the comparison shares: its error type, defaults, seed layout, labels, JSON.

Seeds: render r (1, 2, ...) of the k-th integrator (0, 1, ...) uses ``seed + k * SEED_STRIDE +
r``, and the reference's two halves use ``REFERENCE_SEED_OFFSET + 2 seed`` and the next one, so
no two renders of a comparison share their paths.
"""
from __future__ import annotations

import math

import numpy as np

REFERENCE_INTEGRATOR = "sonar_tof"
DEFAULT_INTEGRATORS = ("sonar_tof", "sonar_mlt")
#: What a comparison sets on an integrator unless ``--param`` (``integrator_params``) sets it.
#: ``sonar_mlt``'s own default, ``split=0``, runs no chains (its scan is ``sonar_tof``'s), so
#: compared as it is, the path tracer was compared with itself. A comparison runs its Metropolis
#: chains over every echo, ``split="off"``, with its other settings at their defaults (one target
#: over the scan, about 2^13 chains in all, ``large_step`` 0.1, small steps 1/128 to 1/4: the best
#: measured on scenes_xml/). Of the splits measured it lost least on ``pile_quay`` (1.4-2.3x
#: ``sonar_tof``'s error at equal time, ``split="auto"`` 2.1-4x; docs/benchmarks.rst), and it
#: is the one whose chains run on every scene: a numeric split or ``auto`` chains only the echoes
#: after a mirror-like bounce, and a scene without mirrors gets no chains.
COMPARE_SETTINGS = {"sonar_mlt": {"split": "off"}}
DEFAULT_BUDGETS = (2.0, 4.0, 8.0, 16.0)
DEFAULT_REPEATS = 2
#: With automatic reference spp the reference gets this many times the path-tracing work of the
#: largest budget: its own relative error is then 1/sqrt(16) = 1/4 of that run's, and inflates
#: that run's error by sqrt(1 + 1/16) - 1 = 3 % (independent errors add in square).
DEFAULT_REFERENCE_FACTOR = 16.0
#: Reference halves use seeds far from those of the runs (see SEED_STRIDE).
REFERENCE_SEED_OFFSET = 0x40000000
#: Render r (1, 2, ...) of the k-th integrator (0, 1, ...) uses seed + k * SEED_STRIDE + r: two
#: integrators never share a seed, so two sonar_tof entries never share their first paths.
SEED_STRIDE = 1 << 20
#: Calibration and warm-up renders use this seed: they are never scored.
WARM_SEED = REFERENCE_SEED_OFFSET - 1
CALIBRATION_START_SPP = 256
MAX_SPP = 1 << 31  # sample indices are 32-bit
#: A reference whose own error exceeds this fraction of the smallest error measured is flagged.
REFERENCE_NOISE_WARNING = 0.5


class CompareError(ValueError):
    """Bad input to the comparison; the message is one line for the user."""


def labels_for(names) -> list[str]:
    """Unique labels: the plugin name, then ``name#2``, ``name#3`` for repeats of it."""
    seen, out = {}, []
    for n in names:
        seen[n] = seen.get(n, 0) + 1
        out.append(n if seen[n] == 1 else f"{n}#{seen[n]}")
    return out


def run_params(name, given=None) -> dict:
    """The parameters integrator ``name`` runs with in a comparison: `COMPARE_SETTINGS`'s for it,
    then ``given`` (the user's ``--param``), which win."""
    return {**COMPARE_SETTINGS.get(name, {}), **(given or {})}


def shown_as(label, params) -> str:
    """``label`` with the parameters it runs with, for the printed table and the JSON:
    ``sonar_mlt (split=off)``; the bare label without parameters."""
    return f"{label} ({', '.join(f'{k}={v}' for k, v in params.items())})" if params else label


def jsonable(obj):
    """``obj`` with numpy values as Python ones and NaN or infinities as None (strict JSON)."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None  # JSON has no NaN
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    return obj
