"""Live benchmark: ``mitsonar live`` at real ping rates, and a soak for memory.

Prints one JSON object (and writes it to ``--out`` if given). Each case runs ``mitsonar live`` in
its own process with ``--records`` (one line per ping: paths, estimated error, latency from the
pose time to the last byte written or the frame published) and a real client:

* ``micron``: scenes_xml/harbour.xml's mechanical head served as a Micron on a pseudo-terminal,
  read by the project's SeaNet driver (`mitsonar.devices.micron.driver.MicronSonar`) with the
  scene's range and bins; the head's timing model (request, listening ``2R/c``, motor step,
  transfer at 115200 Bd) sets the ping rate, each ping's budget its own period;
* ``ping360``: the same head as a Ping360 over UDP, pinged by Blue Robotics' ``brping`` client
  (``transmitAngle``, one gradian a step, the scene's range in 600 samples);
* ``multibeam256``: scenes_xml/harbour.xml's multibeam widened to 256 beams (half the bearing
  step), whole frames at 10 Hz (``--ping-rate 10``), budget 100 ms a frame;
* ``oculus512``: that multibeam as an Oculus M1200d (``--head oculus``: 512 beams at its own
  sine-spaced bearing table, 0..10 m), fired at 10 Hz by the project's driver while poses arrive
  over UDP at 20 Hz; budget one ping period.

For each: pings (frames) answered per second, latency / paths / relative error p50, p95, p99
and, for the multibeam, frames published and late frames skipped.

``--soak SECONDS`` (default 600 when given without a value) instead runs the live Ping360 with
poses at 50 Hz over UDP and brping pinging continuously, and prints the server's resident memory
(RSS, /proc) at the start (serving), after a warm-up (``--warmup``, 60 s), at the end, and its
slope (MB/min, least squares over the samples after the warm-up).

``--baseline-python PATH`` (A/B in one run): PATH is the interpreter of another mitsonar installation
(e.g. an old commit's venv). Each case's ``mitsonar live`` runs under this interpreter (A) and under
PATH (B), alternating case by case (A, B, A, B, ... ``--rounds`` times), with the same client code
(this checkout's); each server starts in the temporary folder, so it imports its own installation.
What each side's ``mitsonar live`` accepts (its ``--head`` choices and flags) is read once from its
``--help`` (`probe`); a case that needs what a side lacks runs on the other side only (e.g.
``oculus512`` needs ``--head oculus``). The JSON gives each side's figures pooled over the rounds
(pings/s, latency p50/p95, paths p50 and mean, error p50/p95) and the ratios A over B (`ab_summary`).

Usage::

    python benchmarks/live.py --seconds 30 [--out live.json]
    python benchmarks/live.py --baseline-python ../old/.venv/bin/python --rounds 2 --seconds 20
    python benchmarks/live.py --cases oculus512 --seconds 30
    python benchmarks/live.py --soak [600]
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import io
import json
import math
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import xml.etree.ElementTree as ET
from typing import NamedTuple

import numpy as np

from mitsonar.devices.ping360.head import Ping360Settings

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HARBOUR = os.path.join(ROOT, "scenes_xml", "harbour.xml")


class Side:
    """One mitsonar installation serving ``mitsonar live``: its interpreter, and what its ``live``
    command accepts (``--head`` choices, flags), read once from its ``--help`` by `probe`. The one
    place where the two sides of an A/B run differ."""

    def __init__(self, label, python, heads=(), flags=(), version=None):
        self.label, self.python, self.version = label, python, version
        self.heads, self.flags = frozenset(heads), frozenset(flags)

    def lacks(self, needs):
        """What of ``needs`` (``--head`` names and flags) this side's ``mitsonar live`` does not accept."""
        return sorted(n if n.startswith("--") else f"--head {n}"
                      for n in needs if n not in (self.flags if n.startswith("--") else self.heads))

    def describe(self):
        return {"python": self.python, "mitsonar": self.version, "heads": sorted(self.heads)}


def _server_env(python):
    """The environment of a ``mitsonar live`` under ``python``: no debug mode; for another
    interpreter, no PYTHONPATH either (it would import this installation's modules)."""
    env = dict(os.environ)
    env.pop("MITSONAR_DEBUG", None)
    if python != sys.executable:
        env.pop("PYTHONPATH", None)
    return env


def _live_help(python, cwd):
    code = ("import sys, mitsonar; print(getattr(mitsonar, '__version__', '?')); sys.argv = ['mitsonar', 'live', '--help']; "
            "import runpy; runpy.run_module('mitsonar', run_name='__main__')")
    return subprocess.run([python, "-c", code], capture_output=True, text=True, cwd=cwd, env=_server_env(python),
                          timeout=300)


def parse_live_help(label, python, text):
    """A `Side` from ``mitsonar live --help``'s text (its first line: the installation's version)."""
    version, _, text = text.partition("\n")
    m = re.search(r"--head \{([^}]*)\}", text)
    heads = m.group(1).split(",") if m else ()
    return Side(label, python, heads, set(re.findall(r"(?<![\w-])--[a-z][a-z0-9-]*", text)), version.strip())


def probe(label, python, cwd, what="--baseline-python"):
    """The `Side` of interpreter ``python`` (``what`` names it in messages); raises ValueError (one
    line) if it cannot run ``mitsonar live``."""
    python = os.path.abspath(python)     # the servers start in another folder; a venv's link kept
    try:
        r = _live_help(python, cwd)
    except OSError as e:
        raise ValueError(f"{what} {python}: cannot run it ({e.strerror})") from None
    if r.returncode != 0 or "--records" not in r.stdout:
        last = (r.stderr.strip().splitlines() or ["no output"])[-1]
        raise ValueError(f"{what} {python}: its `mitsonar live --help` failed or has no --records "
                         f"(need an interpreter with mitsonar installed): {last}")
    return parse_live_help(label, python, r.stdout)


def start(*args, side=None, cwd=None):
    """``mitsonar live`` in a process (under ``side``'s interpreter, this one by default, started in
    ``cwd`` so that ``-m`` imports the installation rather than a checkout in the current folder);
    returns (process, its first lines up to the serving one)."""
    python = sys.executable if side is None else side.python
    proc = subprocess.Popen([python, "-m", "mitsonar", "live", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=_server_env(python), cwd=cwd)
    lines = []
    for line in proc.stdout:
        lines.append(line)
        if line.startswith("live "):
            break
    if not lines or not lines[-1].startswith("live "):
        proc.kill()
        raise RuntimeError(f"mitsonar live did not start: {''.join(lines)} {proc.stderr.read()}")
    return proc, "".join(lines)


def stop(proc) -> str:
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=120)
    if proc.returncode != 0:
        raise RuntimeError(f"mitsonar live ended with {proc.returncode}: {err}")
    return out.strip().splitlines()[-1]


def percentiles(rows, field):
    v = np.array([float(r[field]) for r in rows if r[field] not in ("", None)], np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0:
        return None
    return {f"p{q}": round(float(np.percentile(v, q)), 4) for q in (50, 95, 99)}


def read_records(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


class Run(NamedTuple):
    """One case served once: its records (one dict per ping), the seconds the client ran, the
    server's summary line and the client's own counts."""
    case: str
    rows: list
    seconds: float
    summary: str
    extra: dict


def summarise(run):
    name, rows, seconds, summary, extra = run
    return {"case": name, "pings": len(rows), "seconds": round(seconds, 2),
            "pings_per_s": round(len(rows) / seconds, 2) if seconds else None,
            "latency_ms": percentiles(rows, "latency_ms"), "render_ms": percentiles(rows, "render_ms"),
            "budget_ms": percentiles(rows, "budget_ms"), "paths": percentiles(rows, "paths"),
            "relative_error": percentiles(rows, "error"), "summary": summary, **extra}


def _p(stats, q):
    return None if stats is None else stats[f"p{q}"]


def side_figures(runs):
    """One side's figures over its runs of a case, the records pooled: pings (frames) per second,
    latency p50/p95, paths p50 and mean (a ping's paths are ``2^k`` or ``1.5 x 2^k``: the p50 moves
    in steps, the mean does not), relative error p50/p95, budget p50; None without runs."""
    if not runs:
        return None
    rows = [r for run in runs for r in run.rows]
    seconds = sum(run.seconds for run in runs)
    lat, paths, err, budget = (percentiles(rows, f) if rows else None
                               for f in ("latency_ms", "paths", "error", "budget_ms"))
    return {"runs": len(runs), "pings": len(rows), "seconds": round(seconds, 2),
            "pings_per_s": round(len(rows) / seconds, 2) if seconds else None,
            "latency_ms": {"p50": _p(lat, 50), "p95": _p(lat, 95)}, "paths_p50": _p(paths, 50),
            "paths_mean": round(float(np.mean([float(r["paths"]) for r in rows])), 1) if rows else None,
            "relative_error": {"p50": _p(err, 50), "p95": _p(err, 95)}, "budget_ms_p50": _p(budget, 50),
            "summaries": [run.summary for run in runs]}


def _ratio(a, b):
    return round(a / b, 3) if a is not None and b not in (None, 0) else None


def ab_summary(case, a_runs, b_runs, skipped=None):
    """A case's A/B comparison: each side's `side_figures` and the ratios A over B: ``paths_p50``
    (how many times B's paths A renders; at equal budget when ``budget_ms_p50`` is 1), latency p50
    and p95 (below 1: A answers sooner), pings per second. ``skipped``: {side label: why}."""
    a, b = side_figures(a_runs), side_figures(b_runs)
    out = {"case": case, "A": a, "B": b}
    if skipped:
        out["skipped"] = skipped
    if a and b:
        out["ratios_a_over_b"] = {
            "paths_p50": _ratio(a["paths_p50"], b["paths_p50"]),
            "paths_mean": _ratio(a["paths_mean"], b["paths_mean"]),
            "latency_ms_p50": _ratio(a["latency_ms"]["p50"], b["latency_ms"]["p50"]),
            "latency_ms_p95": _ratio(a["latency_ms"]["p95"], b["latency_ms"]["p95"]),
            "pings_per_s": _ratio(a["pings_per_s"], b["pings_per_s"]),
            "budget_ms_p50": _ratio(a["budget_ms_p50"], b["budget_ms_p50"])}
    return out


def scene_range():
    """The harbour's mechanical head: range_max and bins."""
    root = ET.parse(HARBOUR).getroot()
    s = next(e for e in root.iter("sensor") if e.get("id") == "sonar")
    val = {c.get("name"): c.get("value") for c in s}
    return float(val["range_max"]), int(val["n_bins"])


def micron(seconds, tmp, side=None):
    from mitsonar.devices.micron.driver import MicronSonar
    from mitsonar.devices.micron.seanet import HeadSettings

    records = os.path.join(tmp, "micron.csv")
    proc, text = start(HARBOUR, "--head", "micron", "--sensor", "sonar", "--records", records, side=side, cwd=tmp)
    try:
        port = text.split("live ")[-1].split(" on ")[1].strip()
        rng, bins = scene_range()
        with MicronSonar(port, settings=HeadSettings(range=rng, n_bins=bins), timeout=20) as sonar:
            t0 = time.monotonic()
            n = 0
            while time.monotonic() - t0 < seconds:
                sonar.read_ping()
                n += 1
            dt = time.monotonic() - t0
    finally:
        summary = stop(proc)
    return Run("micron", read_records(records), dt, summary, {"scanlines_read": n})


def brping_client(head):
    import brping

    p = brping.Ping360()
    host, port = head.rsplit(":", 1)
    with contextlib.redirect_stdout(io.StringIO()):
        p.connect_udp(host, int(port))
    if not p.initialize():
        raise RuntimeError("brping could not initialise the live Ping360")
    rng, _ = scene_range()
    # the head's fields for that range as mitsonar's Ping360 client sets them (sample period in
    # 25 ns ticks, Blue Robotics' transmit duration)
    settings = Ping360Settings(range=rng, number_of_samples=600)
    p.set_number_of_samples(settings.number_of_samples)
    p.set_sample_period(settings.sample_period)
    p.set_transmit_duration(settings.transmit_duration)
    return p


def ping360(seconds, tmp, side=None, pose_rate=None, rss=None):
    records = os.path.join(tmp, "ping360.csv")
    extra = ["--pose-url", "udp://127.0.0.1:0"] if pose_rate else []
    proc, text = start(HARBOUR, "--head", "ping360", "--sensor", "sonar", "--port-url", "udp://127.0.0.1:0",
                       "--records", records, *extra, side=side, cwd=tmp)
    stop_poses = threading.Event()
    poses = None
    try:
        if rss is not None:
            rss.append((time.monotonic(), vm_rss(proc.pid)))
        if pose_rate:
            pose_port = int(text.split("poses on udp://127.0.0.1:")[1].split()[0])
            poses = threading.Thread(target=send_poses, args=(pose_port, pose_rate, stop_poses), daemon=True)
            poses.start()
        head = text.split("live Ping360 on udp://")[1].split()[0]
        p = brping_client(head)
        t0 = time.monotonic()
        n, angle, next_sample = 0, 0, t0
        while time.monotonic() - t0 < seconds:
            if p.transmitAngle(angle) is not None:
                n += 1
            angle = (angle + 1) % 400
            if rss is not None and time.monotonic() >= next_sample:
                rss.append((time.monotonic(), vm_rss(proc.pid)))
                next_sample += 5.0
        dt = time.monotonic() - t0
        if rss is not None:
            rss.append((time.monotonic(), vm_rss(proc.pid)))
        p.iodev.close()
    finally:
        stop_poses.set()
        summary = stop(proc)
    return Run("ping360", read_records(records), dt, summary, {"replies": n})


def widened_multibeam(beams):
    """The XML root of scenes_xml/harbour.xml with its multibeam widened to ``beams`` beams
    across the same swath (the bearing step scaled), as the ``multibeam256`` case serves it."""
    root = ET.parse(HARBOUR).getroot()
    mb = next(e for e in root.iter("sensor") if e.get("id") == "multibeam")
    el = {c.get("name"): c for c in mb}
    step = float(el["bearing_step"].get("value")) * int(el["n_pings"].get("value")) / beams
    el["n_pings"].set("value", str(beams))
    el["bearing_step"].set("value", repr(step))
    return root


def multibeam(seconds, tmp, side=None, beams=256, rate=10.0):
    root = widened_multibeam(beams)
    scene = os.path.join(tmp, "harbour_mb256.xml")
    ET.ElementTree(root).write(scene)
    records = os.path.join(tmp, "multibeam.csv")
    proc, _ = start(scene, "--ping-rate", str(rate), "--records", records, side=side, cwd=tmp)
    t0 = time.monotonic()
    time.sleep(seconds)
    dt = time.monotonic() - t0
    summary = stop(proc)
    rows = read_records(records)
    skipped = int(summary.split(" late frames skipped")[0].rsplit(" ", 1)[1]) if "late frames skipped" in summary else 0
    return Run(f"multibeam{beams}", rows, dt, summary, {"rate_hz": rate, "frames_skipped": skipped})


def oculus(seconds, tmp, side=None, beams=512, rate=10.0, range_m=10.0, pose_rate=20.0):
    """``mitsonar live --head oculus``: the harbour's multibeam at an M1200d's low-frequency mode (its
    own sine-spaced table of ``beams`` bearings, 0..``range_m``), fired at ``rate`` Hz by the
    project's driver while poses arrive over UDP at ``pose_rate`` Hz; each ping's budget is its
    period. Latency: from the ping's time (its render's start) to the ping result written."""
    import mitsonar.presets.oculus as presets
    from mitsonar.devices.oculus.driver import OculusSonar, fire_message

    mode = presets.model("M1200d").mode(1)
    root = ET.parse(HARBOUR).getroot()
    mb = next(e for e in root.iter("sensor") if e.get("id") == "multibeam")
    for c in [c for c in mb if c.get("name") in ("n_pings", "bearing_start", "bearing_step", "range_min", "range_max",
                                                  "n_bins", "beamwidth_h", "beamwidth_v", "frequency")]:
        mb.remove(c)
    table = presets.bearing_table(mode.aperture, beams) / 100.0
    ET.SubElement(mb, "string", name="bearings", value=" ".join(f"{b:.2f}" for b in table))
    for name, value, tag in (("range_min", 0.0, "float"), ("range_max", range_m, "float"), ("n_bins", 400, "integer"),
                             ("beamwidth_h", mode.beamwidth_h, "float"), ("beamwidth_v", mode.beamwidth_v, "float"),
                             ("frequency", mode.frequency, "float")):
        ET.SubElement(mb, tag, name=name, value=str(value))
    scene = os.path.join(tmp, f"harbour_oculus{beams}.xml")
    ET.ElementTree(root).write(scene)
    records = os.path.join(tmp, "oculus.csv")
    udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    udp.bind(("127.0.0.1", 0))
    status_port = udp.getsockname()[1]
    udp.close()
    proc, text = start(scene, "--head", "oculus", "--sensor", "multibeam", "--port-url", "tcp://127.0.0.1:0",
                       "--status-port", str(status_port), "--pose-url", "udp://127.0.0.1:0", "--records", records,
                       side=side, cwd=tmp)
    stop_poses = threading.Event()
    frames = 0
    try:
        pose_port = int(text.split("poses on udp://127.0.0.1:")[1].split()[0])
        poses = threading.Thread(target=send_poses, args=(pose_port, pose_rate, stop_poses), daemon=True)
        poses.start()
        port = int(text.split("tcp://127.0.0.1:")[1].split()[0])
        with OculusSonar("127.0.0.1", port, fire=fire_message(rate=rate, range=range_m, gain=100, beams=beams),
                         timeout=30.0) as sonar:
            t0 = time.monotonic()
            while time.monotonic() - t0 < seconds:
                sonar.scan()
                frames += 1
            dt = time.monotonic() - t0
    finally:
        stop_poses.set()
        summary = stop(proc)
    return Run(f"oculus{beams}", read_records(records), dt, summary,
               {"rate_hz": rate, "range_m": range_m, "pose_rate_hz": pose_rate, "frames_read": frames})


def send_poses(port, rate, stop_event):
    """Poses at ``rate`` Hz: the vehicle circling slowly in the basin (yaw turning)."""
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    t0 = time.monotonic()
    k = 0
    while not stop_event.is_set():
        t = k / rate
        yaw = 0.2 * t
        h = yaw / 2
        d = {"t": t, "position": [2.0 * math.cos(0.05 * t), 2.0 * math.sin(0.05 * t), 0.0],
             "orientation": [0.0, 0.0, math.sin(h), math.cos(h)]}
        tx.sendto(json.dumps(d).encode(), ("127.0.0.1", port))
        k += 1
        stop_event.wait(max(0.0, t0 + k / rate - time.monotonic()))
    tx.close()


def vm_rss(pid) -> float:
    """Resident memory of process ``pid`` in MB (/proc/PID/status VmRSS)."""
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return math.nan


def soak(seconds, warmup, tmp):
    rss = []
    result = summarise(ping360(seconds, tmp, pose_rate=50.0, rss=rss))
    t = np.array([r[0] for r in rss]) - rss[0][0]
    m = np.array([r[1] for r in rss])
    after = t >= warmup
    slope = float(np.polyfit(t[after] / 60.0, m[after], 1)[0]) if after.sum() >= 2 else math.nan
    k = int(np.argmax(after)) if after.any() else len(m) - 1
    result.update(case="soak", pose_rate_hz=50.0, rss_mb={
        "start": round(float(m[0]), 1), "after_warmup": round(float(m[k]), 1), "end": round(float(m[-1]), 1),
        "slope_mb_per_min_after_warmup": round(slope, 3), "warmup_s": warmup, "samples": len(m)})
    return result


# each case: its function and what it needs of a side's `mitsonar live` (--head names, flags)
CASES = {"micron": (micron, ("micron", "--head", "--sensor", "--records")),
         "ping360": (ping360, ("ping360", "--head", "--sensor", "--port-url", "--records")),
         "multibeam256": (multibeam, ("--ping-rate", "--records")),
         "oculus512": (oculus, ("oculus", "--head", "--sensor", "--port-url", "--status-port", "--pose-url", "--records"))}


def parse_args(argv=None):
    """The arguments, checked before any work (one line naming the flag and what it allows)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="seconds per case (default 30)")
    ap.add_argument("--soak", type=float, nargs="?", const=600.0, default=None, metavar="SECONDS",
                    help="soak instead: poses at 50 Hz and brping pinging for SECONDS (default 600)")
    ap.add_argument("--warmup", type=float, default=60.0, help="soak: seconds before the RSS slope (default 60)")
    ap.add_argument("--cases", default="micron,ping360,multibeam256",
                    help=f"comma-separated cases of {', '.join(CASES)} (default micron,ping360,multibeam256)")
    ap.add_argument("--baseline-python", default=None, metavar="PATH",
                    help="A/B: also serve each case with this interpreter's mitsonar (B), alternating with this one (A)")
    ap.add_argument("--rounds", type=int, default=1, help="runs of each case (per side with --baseline-python; default 1)")
    ap.add_argument("--out", default=None, help="also write the JSON here")
    args = ap.parse_args(argv)
    args.cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    bad = [c for c in args.cases if c not in CASES]
    if bad or not args.cases:
        ap.error(f"--cases: unknown case(s) {', '.join(bad) or '(none given)'}; allowed: {', '.join(CASES)}")
    if args.rounds < 1:
        ap.error(f"--rounds: {args.rounds}; allowed: an integer >= 1")
    if not args.seconds > 0:
        ap.error(f"--seconds: {args.seconds}; allowed: a number > 0")
    if args.baseline_python is not None:
        if args.soak is not None:
            ap.error("--baseline-python: not with --soak (the soak runs this installation only)")
        if not (os.path.isfile(args.baseline_python) and os.access(args.baseline_python, os.X_OK)):
            ap.error(f"--baseline-python: {args.baseline_python} is not an executable file; allowed: a Python "
                     "interpreter with mitsonar installed")
    return args


def ab_plan(cases, rounds, sides):
    """The order of an A/B run: case by case, each round A then B (A, B, A, B, ...); a side that
    lacks what a case needs is left out of that case. Returns (plan of (case, side), {case: {label: why}})."""
    plan, skipped = [], {}
    for case in cases:
        needs = CASES[case][1]
        runnable = []
        for side in sides:
            lacks = side.lacks(needs)
            if lacks:
                skipped.setdefault(case, {})[side.label] = f"its mitsonar live has no {', '.join(lacks)}"
            else:
                runnable.append(side)
        plan += [(case, side) for _ in range(rounds) for side in runnable]
    return plan, skipped


def run_ab(args, tmp):
    a = probe("A", sys.executable, tmp, what="this interpreter")
    b = probe("B", args.baseline_python, tmp)
    plan, skipped = ab_plan(args.cases, args.rounds, (a, b))
    runs = {(case, side.label): [] for case in args.cases for side in (a, b)}
    for k, (case, side) in enumerate(plan):
        print(f"[{k + 1}/{len(plan)}] {case} {side.label}", file=sys.stderr, flush=True)
        runs[case, side.label].append(CASES[case][0](args.seconds, tempfile.mkdtemp(dir=tmp), side=side))
    return {"benchmark": "live A/B", "cpus": os.cpu_count(), "scene": "scenes_xml/harbour.xml",
            "seconds_per_run": args.seconds, "rounds": args.rounds, "order": "case by case, A then B each round",
            "A": a.describe(), "B": b.describe(),
            "cases": [ab_summary(c, runs[c, "A"], runs[c, "B"], skipped.get(c)) for c in args.cases]}


def main(argv=None) -> int:
    args = parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        try:
            if args.soak is not None:
                result = {"benchmark": "live soak", "cpus": os.cpu_count(), **soak(args.soak, args.warmup, tmp)}
            elif args.baseline_python is not None:
                result = run_ab(args, tmp)
            else:
                result = {"benchmark": "live", "cpus": os.cpu_count(), "scene": "scenes_xml/harbour.xml",
                          "cases": [summarise(CASES[c][0](args.seconds, tempfile.mkdtemp(dir=tmp)))
                                    for c in args.cases for _ in range(args.rounds)]}
        except ValueError as e:
            print(f"live.py: error: {e}", file=sys.stderr)
            return 2
    text = json.dumps(result, indent=1)
    print(text)
    if args.out:
        with open(args.out + ".part", "w") as f:
            f.write(text + "\n")
        os.replace(args.out + ".part", args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
