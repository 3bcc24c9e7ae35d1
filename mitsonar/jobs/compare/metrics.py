"""Errors of a render against the reference, their summary over repeats, equal-time ratios.

Errors are over range bins: ``rel_l2 = ||est - ref||_2 / ||ref||_2`` and
``rel_l1 = sum|est - ref| / sum|ref|``, over the whole scan, per ping, and over range windows
(regions). Over repeats they are combined as a root mean square, which estimates the expected
squared error. The reference has noise of its own, estimated from its two independent halves
(`self_errors`); ``rel_l2_debiased = sqrt(rel_l2^2 - self_rel_l2^2)`` removes it, because the
render's and the reference's errors are independent and so add in square.
"""
from __future__ import annotations

import math

import numpy as np

from mitsonar.jobs.compare.common import CompareError


def error_metrics(estimate, reference, reference_self_l2=0.0) -> dict:
    """Relative errors of one render against the reference.

    =================== ==========================================================================
    estimate            float array (n_pings, n_bins)
    reference           float array, same shape
    reference_self_l2   the reference's own relative L2 error, removed in ``rel_l2_debiased``
    =================== ==========================================================================

    Returns ``rel_l2``, ``rel_l1``, ``rel_l2_debiased`` (floats) and ``per_ping_rel_l2``,
    ``per_ping_rel_l1`` (float arrays, NaN where the reference ping is all zero).
    """
    est = np.asarray(estimate, np.float64)
    ref = np.asarray(reference, np.float64)
    if est.shape != ref.shape:
        raise CompareError(f"estimate shape {est.shape} differs from the reference's {ref.shape}")
    d = est - ref
    l2_ref, l1_ref = np.linalg.norm(ref), np.abs(ref).sum()
    rel_l2 = float(np.linalg.norm(d) / l2_ref) if l2_ref > 0 else float("nan")
    rel_l1 = float(np.abs(d).sum() / l1_ref) if l1_ref > 0 else float("nan")
    with np.errstate(divide="ignore", invalid="ignore"):
        ping_l2 = np.linalg.norm(d, axis=-1) / np.linalg.norm(ref, axis=-1)
        ping_l1 = np.abs(d).sum(-1) / np.abs(ref).sum(-1)
    empty = np.abs(ref).sum(-1) == 0
    ping_l2[empty] = np.nan
    ping_l1[empty] = np.nan
    return {"rel_l2": rel_l2, "rel_l1": rel_l1,
            "rel_l2_debiased": debias(rel_l2, reference_self_l2),
            "per_ping_rel_l2": ping_l2, "per_ping_rel_l1": ping_l1}


def debias(err, self_err):
    """``sqrt(max(err^2 - self_err^2, 0))``: an error with the reference's own error removed."""
    return float(math.sqrt(max(err * err - self_err * self_err, 0.0))) if math.isfinite(err) else err


def rms(values):
    """Root mean square of ``values`` (NaN for none)."""
    v = np.asarray(values, np.float64)
    return float(np.sqrt(np.mean(v * v))) if v.size else float("nan")


def region_mask(ranges, lo, hi):
    """The bins whose centre range lies in ``[lo, hi)``."""
    return (ranges >= lo) & (ranges < hi)


def self_errors(reference, half_difference, mask=None) -> dict:
    """The reference's own relative errors (whole scan, or the bins where ``mask`` is true).

    The reference is the mean of two independent halves h1, h2 whose errors e1, e2 have the same
    distribution, so its error (e1 + e2) / 2 is distributed like (h1 - h2) / 2.
    """
    ref = reference if mask is None else reference[:, mask]
    d = half_difference if mask is None else half_difference[:, mask]
    l2, l1 = np.linalg.norm(ref), np.abs(ref).sum()
    return {"self_rel_l2": float(np.linalg.norm(d) / (2 * l2)) if l2 > 0 else float("nan"),
            "self_rel_l1": float(np.abs(d).sum() / (2 * l1)) if l1 > 0 else float("nan")}


def score(hist, reference, self_l2, masks, region_self_l2) -> dict:
    """`error_metrics` of one render, plus ``regions``: ``{name: error_metrics}`` over the bins of
    each mask in ``masks`` (``{name: bool array (n_bins,)}``), debiased by ``region_self_l2[name]``."""
    m = error_metrics(hist, reference, self_l2)
    m["regions"] = {rn: error_metrics(hist[:, mk], reference[:, mk], region_self_l2[rn]) for rn, mk in masks.items()}
    return m


def summarise(label, budget, spp, seeds, secs, metrics, regions) -> dict:
    """One entry of ``runs``: the repeats' `score` results combined as a root mean square.

    ``seconds_vs_budget`` is the mean measured time over the budget (1 when the spp search filled
    the budget exactly).
    """
    def stack(key):
        return np.stack([m[key] for m in metrics])

    per_ping_l2 = np.sqrt(np.mean(stack("per_ping_rel_l2") ** 2, axis=0))
    per_ping_l1 = np.sqrt(np.mean(stack("per_ping_rel_l1") ** 2, axis=0))
    run = {
        "integrator": label, "budget_s": float(budget), "spp": int(spp), "seeds": seeds,
        "seconds": [float(s) for s in secs], "seconds_mean": float(np.mean(secs)),
        "seconds_vs_budget": float(np.mean(secs)) / float(budget),
        "rel_l2": rms([m["rel_l2"] for m in metrics]),
        "rel_l1": rms([m["rel_l1"] for m in metrics]),
        "rel_l2_debiased": rms([m["rel_l2_debiased"] for m in metrics]),
        "rel_l2_each": [float(m["rel_l2"]) for m in metrics],
        "rel_l1_each": [float(m["rel_l1"]) for m in metrics],
        "per_ping_rel_l2": _nullable(per_ping_l2),
        "per_ping_rel_l1": _nullable(per_ping_l1),
        "regions": {},
    }
    for rn in regions:
        rm = [m["regions"][rn] for m in metrics]
        run["regions"][rn] = {"rel_l2": rms([m["rel_l2"] for m in rm]),
                              "rel_l1": rms([m["rel_l1"] for m in rm]),
                              "rel_l2_debiased": rms([m["rel_l2_debiased"] for m in rm])}
    return run


def _nullable(values):
    return [float(v) if math.isfinite(v) else None for v in np.asarray(values, np.float64)]


def equal_time_ratios(runs, labels, budgets, region_names=(), metric="rel_l2_debiased") -> list:
    """Error ratios against the first integrator (the baseline), per budget.

    ``ratio_raw = err_base / err`` and ``ratio_time_adjusted = err_base sqrt(t_base) / (err
    sqrt(t))`` with ``t`` the measured mean seconds: the ratio at exactly equal time for errors
    that fall as 1/sqrt(t), as unbiased Monte Carlo errors do. > 1: lower error than the
    baseline. ``metric`` picks the error.
    """
    by = {(r["integrator"], r["budget_s"]): r for r in runs}
    out = []
    base = labels[0]
    for budget in budgets:
        b = by[(base, float(budget))]
        entry = {"budget_s": float(budget), "baseline": base, "metric": metric, "ratios": {}}
        for lab in labels[1:]:
            o = by[(lab, float(budget))]
            # A debiased error of 0 (below the reference's own noise) gives no ratio: fall back
            # to the raw error for that pair and say so.
            m = metric if (b[metric] > 0 and o[metric] > 0) else metric.replace("_debiased", "")
            item = _ratio(b[m], o[m], b["seconds_mean"], o["seconds_mean"])
            item["metric"] = m
            item["regions"] = {rn: _ratio(b["regions"][rn][metric], o["regions"][rn][metric],
                                          b["seconds_mean"], o["seconds_mean"]) for rn in region_names}
            entry["ratios"][lab] = item
        out.append(entry)
    return out


def _ratio(e_base, e, t_base, t):
    ok = e > 0 and math.isfinite(e) and math.isfinite(e_base)
    raw = e_base / e if ok else float("nan")
    adj = e_base * math.sqrt(t_base) / (e * math.sqrt(t)) if ok and t > 0 else float("nan")
    return {"ratio_raw": raw, "ratio_time_adjusted": adj}


__all__ = ["equal_time_ratios", "error_metrics", "score", "self_errors", "summarise"]
