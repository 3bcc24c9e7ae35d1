"""SGD step schedules (thesis 4.3.1). ``t`` counts samples seen, ``n`` is the epoch size."""
from __future__ import annotations

import math

SCHEDULES = ("thesis", "classic", "ramos_ott", "constant")


def step_size(schedule: str, t: float, n: float, eta0: float, k1: float = 1.0, t0: float | None = None,
              alpha: float = 1e-4, l1_ratio: float = 0.15) -> float:
    """Step ``eta_t``.

    ``thesis``    eq. 4.12: ``eta0/2 (1 / ((1 + t/n) log_n(n + t)) + k1 exp(-t/n))``
    ``classic``   eq. 4.11: ``eta0 / (1 + t/n)``
    ``ramos_ott`` ``1 / (alpha alpha_2 (t0 + t))`` with the l2 share ``alpha_2 = 1 - l1_ratio``;
                  ``t0`` defaults to ``1 / (alpha alpha_2 eta0)`` so the first step is ``eta0``
    ``constant``  ``eta0``
    """
    n = max(float(n), 2.0)
    if schedule == "thesis":
        return 0.5 * eta0 * (1.0 / ((1.0 + t / n) * (math.log(n + t) / math.log(n))) + k1 * math.exp(-t / n))
    if schedule == "classic":
        return eta0 / (1.0 + t / n)
    if schedule == "ramos_ott":
        a2 = alpha * (1.0 - l1_ratio)
        if a2 <= 0:
            raise ValueError("HilbertMap: the ramos_ott schedule needs alpha * (1 - l1_ratio) > 0")
        if t0 is None:
            t0 = 1.0 / (a2 * eta0)
        return 1.0 / (a2 * (t0 + t))
    if schedule == "constant":
        return eta0
    raise ValueError(f"HilbertMap: unknown schedule {schedule!r}; choose one of {', '.join(SCHEDULES)}")
