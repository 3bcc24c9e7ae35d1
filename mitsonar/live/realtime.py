"""Real time for ``mitsonar live``: each ping fits a time budget, and what it cost is recorded.

* `PathBudget`: how many paths the next ping renders. The time per path is measured on every
  ping (``seconds / paths``, fixed costs included) and smoothed by an exponential average; the
  next ping takes ``headroom * budget / (time per path)`` paths, rounded down onto a fixed ladder
  of sizes (`SPP_LADDER`, ``2**k`` and ``1.5 x 2**k``). With ``t(n) = a + b n`` (a fixed cost ``a``), the
  choice ``n' = B n / t(n)`` converges to ``t(n) = B`` (its fixed point; the map contracts by
  ``a / B`` per ping). Choosing another size does not recompile the path kernels (the number of
  paths is a launch size, not a constant of the kernels: tests/test_live_realtime.py checks it);
  a new pass size records the frozen pass once (tens of ms), hence few sizes.
* `ErrorModel`: the relative error of a ping's echo intensity,
  ``e(n) = ||I_n - E[I]||_2 / ||E[I]||_2`` over the row's bins at ``n`` paths, measured once on
  the scene at start (`ErrorModel.measure`: the sample variance of ``m`` independent renders at
  one pose, at 16, 64, ... 4096 paths), interpolated between and extended beyond as
  ``1 / sqrt(n)``.
* `PingLog`: one record per ping or frame (time, pose time, paths, estimated error, render and
  latency seconds, budget), percentiles for the summary (p50, p95, p99 of latency, paths and
  error), and optionally a file of records (``.csv`` or ``.jsonl``) written under a temporary
  name and renamed on `PingLog.close` (removed by `PingLog.discard`).
* `WireClock`: stamps a ping's record when the last byte of its reply is written to the port
  (latency: the ping's pose time to its bytes written).
"""
from __future__ import annotations

import json
import math
import os
import threading
from collections import deque

import numpy as np

__all__ = ["SPP_LADDER", "PathBudget", "ErrorModel", "CALIBRATION_PATHS", "PingLog", "WireClock", "RECORD_FIELDS", "SUMMARY_FIELDS", "check_records_path"]

#: the sizes (paths per ping) a budgeted ping may take: 16 .. 2**22, 2**k and 1.5 x 2**k. Few on
#: purpose: no size compiles new kernels, but each pass size is a recording of the frozen pass
#: (``plugins/integrators/paths/frozen_pass.py``: tens of ms to record, at most ``MAX_RECORDINGS`` = 32 kept, all
#: dropped past that). A pass holds at most 2**16 paths (fewer per beam for a wide multibeam, a
#: power of two): a size past it is passes of the largest and one of 0 or half of it, so these
#: sizes use 25 pass sizes in all.
SPP_LADDER = tuple(sorted(n for k in range(3, 22) for n in (2 << k, 3 << k) if n <= 1 << 22))


class PathBudget:
    """The paths of the next ping under a budget of ``budget`` seconds (module doc).

    ``first``: paths of the first ping before any measurement (``seconds_per_path`` given
    instead starts the average). ``alpha``: weight of the newest measurement. ``headroom``:
    the fraction of the budget aimed at (the rest absorbs the jitter of a loaded machine).
    """

    def __init__(self, budget: float, *, first: int = 64, seconds_per_path: float | None = None,
                 alpha: float = 0.3, headroom: float = 0.8, ladder=SPP_LADDER):
        if not (math.isfinite(budget) and budget > 0):
            raise ValueError(f"budget: {budget!r} s is not allowed (a positive number of seconds)")
        self.budget, self.alpha, self.headroom = float(budget), float(alpha), float(headroom)
        self.ladder = tuple(int(n) for n in ladder)
        self.per_path = None if seconds_per_path is None else float(seconds_per_path)
        self._first = self.quantise(first)

    def quantise(self, n: float) -> int:
        """The largest ladder size at most ``n`` (the smallest size for less)."""
        k = int(np.searchsorted(self.ladder, n, side="right")) - 1
        return self.ladder[max(k, 0)]

    def next(self, budget: float | None = None) -> int:
        """Paths for the next ping (``budget`` s overriding the default for this one)."""
        if self.per_path is None:
            return self._first
        b = self.budget if budget is None else float(budget)
        return self.quantise(self.headroom * b / self.per_path)

    def measured(self, paths: int, seconds: float) -> None:
        """Update the time per path from a ping of ``paths`` paths that took ``seconds``."""
        per = max(float(seconds), 1e-9) / max(int(paths), 1)
        self.per_path = per if self.per_path is None else (1 - self.alpha) * self.per_path + self.alpha * per


#: the paths at which `ErrorModel.measure` measures a scene's error
CALIBRATION_PATHS = (16, 64, 256, 1024, 4096)


class ErrorModel:
    """A ping's relative intensity error at ``n`` paths, measured on the scene (module doc).

    ``table``: ``{paths: relative error}``. Between measured sizes the error is interpolated
    log-log; below the smallest it is the smallest's; beyond the largest it falls as Monte
    Carlo's ``1 / sqrt(n)`` (the slowest a stratified sampler's error falls: renders' error at
    few paths falls faster, 5x from 16 to 64 paths in scenes_xml/box.xml, so no single power
    law fits, hence the table).
    """

    def __init__(self, table=None):
        self.table = {} if table is None else {int(k): float(v) for k, v in table.items()}

    @staticmethod
    def relative_error(estimate, reference) -> float:
        """``||estimate - reference||_2 / ||reference||_2`` (NaN for a zero reference)."""
        ref = np.asarray(reference, np.float64).ravel()
        norm = float(np.linalg.norm(ref))
        if norm == 0.0:
            return math.nan
        return float(np.linalg.norm(np.asarray(estimate, np.float64).ravel() - ref)) / norm

    @staticmethod
    def spread(rows) -> float:
        """The relative error of one of ``m >= 2`` independent renders ``rows`` (m, bins...) of one
        ping: ``sqrt(sum_b var_b) / ||mean||`` with ``var_b`` the unbiased sample variance of
        bin ``b`` (NaN if the mean is zero: nothing in view)."""
        r = np.asarray(rows, np.float64).reshape(len(rows), -1)
        if r.shape[0] < 2:
            raise ValueError("ErrorModel.spread needs at least 2 independent renders")
        mean = r.mean(axis=0)
        norm2 = float(mean @ mean)
        if norm2 == 0.0:
            return math.nan
        return math.sqrt(float(r.var(axis=0, ddof=1).sum()) / norm2)

    @classmethod
    def measure(cls, render, repeats: int = 6, paths=CALIBRATION_PATHS) -> "ErrorModel":
        """The table from ``repeats`` independent renders at each of ``paths``:
        ``render(paths, i)`` returns the intensity of render ``i`` (its own seed) of one ping."""
        return cls({n: cls.spread([render(n, i) for i in range(repeats)]) for n in paths})

    def __call__(self, paths: int) -> float:
        if not self.table:
            return math.nan
        n = max(int(paths), 1)
        ns = sorted(self.table)
        es = [self.table[k] for k in ns]
        if n <= ns[0]:
            return es[0]
        if n >= ns[-1]:
            return es[-1] * math.sqrt(ns[-1] / n)
        k = int(np.searchsorted(ns, n)) - 1
        if not (es[k] > 0 and es[k + 1] > 0):
            return max(es[k], es[k + 1])
        f = math.log(n / ns[k]) / math.log(ns[k + 1] / ns[k])
        return math.exp((1 - f) * math.log(es[k]) + f * math.log(es[k + 1]))


#: the fields of a record, in the order of a CSV file's columns
RECORD_FIELDS = ("ping", "t", "pose_time", "bearing", "paths", "error", "render_ms", "latency_ms", "budget_ms")


_RECORDS_WORDS = {
    "directory": "--records {path}: is a folder; expected a file name ending in .csv or .jsonl",
    "extension": "--records {path}: expected a file name ending in .csv or .jsonl",
    "no_folder": "--records {path}: folder {folder} does not exist",
    "not_writable": "--records {path}: folder {folder} is not writable",
}


def check_records_path(path) -> str:
    """``path`` if it ends in ``.csv`` or ``.jsonl``, is not a folder and its folder exists and
    is writable (`mitsonar._files.check_output_file`); ValueError naming it."""
    from mitsonar._files import check_output_file

    return check_output_file(path, ValueError, extensions=(".csv", ".jsonl"), force=True, words=_RECORDS_WORDS)


#: the fields `PingLog` keeps the percentiles of
SUMMARY_FIELDS = ("latency_ms", "paths", "error", "render_ms")


class PingLog:
    """Records of pings (module doc). ``keep``: the pings the percentiles are taken over (the
    newest, in a ring of numbers allocated once: memory stays flat in long sessions);
    ``records``: the newest 256 records themselves. ``path``: the records file (None: none).
    Thread-safe: heads, frame loops and the summary's signal handler use it together."""

    def __init__(self, path=None, keep: int = 10000):
        self.records: deque = deque(maxlen=256)
        self._ring = np.full((int(keep), len(SUMMARY_FIELDS)), np.nan)
        self.count = 0
        self.skipped = 0
        self._lock = threading.Lock()
        self.path = None if path is None else check_records_path(path)
        self._file = None
        if self.path is not None:
            self._tmp = f"{self.path}.part"
            self._file = open(self._tmp, "w", encoding="utf-8", newline="")
            if self.path.lower().endswith(".csv"):
                self._file.write(",".join(RECORD_FIELDS) + "\n")

    def add(self, record: dict) -> None:
        """Keep ``record`` (fields of `RECORD_FIELDS`) and write its line."""
        with self._lock:
            self._ring[self.count % len(self._ring)] = [_number(record.get(k)) for k in SUMMARY_FIELDS]
            self.count += 1
            self.records.append(record)
            if self._file is not None:
                if self.path.lower().endswith(".csv"):
                    self._file.write(",".join(_csv(record.get(k)) for k in RECORD_FIELDS) + "\n")
                else:
                    self._file.write(json.dumps({k: _json(record.get(k)) for k in RECORD_FIELDS}) + "\n")
                self._file.flush()

    def close(self) -> None:
        """Close the records file and give it its name (once)."""
        with self._lock:
            if self._file is not None:
                self._file.close()
                self._file = None
                os.replace(self._tmp, self.path)

    def discard(self) -> None:
        """Close the records file and remove it (a session that failed to start leaves no file)."""
        with self._lock:
            if self._file is not None:
                self._file.close()
                self._file = None
                if os.path.exists(self._tmp):
                    os.remove(self._tmp)

    def percentiles(self, field: str, qs=(50, 95, 99)):
        """The percentiles of ``field`` (one of `SUMMARY_FIELDS`) over the kept pings (finite
        values); None if none."""
        with self._lock:
            v = self._ring[:min(self.count, len(self._ring)), SUMMARY_FIELDS.index(field)].copy()
        v = v[np.isfinite(v)]
        return None if v.size == 0 else [float(np.percentile(v, q)) for q in qs]

    def summary(self) -> str:
        """``latency ms p50 a, p95 b, p99 c; paths ...; error ...`` (empty before any ping)."""
        parts = []
        for field, label, fmt in (("latency_ms", "latency ms", "{:.1f}"), ("paths", "paths", "{:.0f}"),
                                  ("error", "error", "{:.3g}")):
            p = self.percentiles(field)
            if p is not None:
                parts.append(f"{label} p50 {fmt.format(p[0])}, p95 {fmt.format(p[1])}, p99 {fmt.format(p[2])}")
        if self.skipped:
            parts.append(f"{self.skipped} late frames skipped")
        return "; ".join(parts)


def _number(v) -> float:
    return math.nan if v is None else float(v)


def _csv(v) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if math.isnan(v) else repr(v)
    return str(v)


def _json(v):
    if isinstance(v, float) and not math.isfinite(v):
        return None
    return v


class WireClock:
    """Which reply ends where in the bytes a head writes (module doc): `queued` counts bytes put
    on the way to the port, in order (``done(now)`` given with a reply's bytes is called when
    its last byte has been written); `wrote` counts bytes written; `resync` forgets the
    replies in flight (a head that dropped its output buffer)."""

    def __init__(self):
        self.queued = 0
        self.written = 0
        self._pending: deque = deque()
        self._lock = threading.Lock()

    def queue(self, nbytes: int, done=None) -> None:
        with self._lock:
            self.queued += int(nbytes)
            if done is not None:
                self._pending.append((self.queued, done))

    def wrote(self, nbytes: int, now: float) -> None:
        fired = []
        with self._lock:
            self.written += int(nbytes)
            while self._pending and self._pending[0][0] <= self.written:
                fired.append(self._pending.popleft()[1])
        for done in fired:
            done(now)

    def resync(self) -> None:
        with self._lock:
            self._pending.clear()
            self.written = self.queued
