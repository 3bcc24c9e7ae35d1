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
