"""Dataset benchmark (issue 27): samples per second of `mitsonar dataset` for 1, 2 and all local
workers, like for like.

Dr.Jit already spreads one render over every core, so the comparison keeps the cores fixed: N
workers with cores / N render threads each against 1 worker with all of them. ``ratio`` is
samples/s of N workers over samples/s of 1 worker (target: >= 0.9, i.e. the distribution layer
costs under 10 %). Each run writes a fresh temporary folder. Two rates per run:

  * ``samples_per_s``: samples over the whole call (starting the worker processes, importing
    Mitsuba, compiling kernels, writing shards and the manifest);
  * ``steady_samples_per_s``: samples after each worker's first one, over the time from then to
    the last (what a long run sees: start-up paid once).

Prints one JSON object. Usage:
    python benchmarks/dataset.py [--config examples/dataset_small.yaml] [--samples 24] [--spp 1024] [--engine ray]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))


class _Clock:
    def __init__(self):
        self.times = []

    def update(self, n=1):
        self.times.append(time.perf_counter())


def run(cfg, workers, threads, engine):
    from mitsonar.jobs.dataset import generate_dataset

    clock = _Clock()
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        generate_dataset(cfg, os.path.join(tmp, "ds"), workers=workers, threads=threads, progress=clock,
                         engine=engine)
        total = time.perf_counter() - t0
    n = len(clock.times)
    k = min(max(workers, 1), n - 1)
    steady = (n - k) / (clock.times[-1] - clock.times[k - 1]) if n > k >= 1 else float("nan")
    return {"workers": workers, "threads_per_worker": threads, "samples": n, "seconds": round(total, 3),
            "samples_per_s": round(n / total, 4), "steady_samples_per_s": round(steady, 4)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--config", default=os.path.join(HERE, "..", "examples", "dataset_small.yaml"))
    ap.add_argument("--samples", type=int, default=24)
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--engine", choices=("local", "ray"), default="local", help="local processes (default) or Ray actors")
    args = ap.parse_args(argv)

    from mitsonar.jobs.dataset import read_config
    from mitsonar.jobs.dataset.runner import _cores

    cfg = read_config(args.config)
    cfg.update(samples=args.samples, spp=args.spp)
    cores = _cores()
    counts = sorted({1, 2, cores})
    runs = [run(cfg, w, max(1, cores // w), args.engine) for w in counts]
    base = runs[0]
    for r in runs:
        r["ratio"] = round(r["samples_per_s"] / base["samples_per_s"], 3)
        r["steady_ratio"] = round(r["steady_samples_per_s"] / base["steady_samples_per_s"], 3)
    print(json.dumps({"benchmark": "dataset", "config": os.path.relpath(args.config), "samples": args.samples,
                      "spp": args.spp, "engine": args.engine, "cores": cores, "python": platform.python_version(),
                      "runs": runs}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
