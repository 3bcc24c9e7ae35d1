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

Usage::

    python benchmarks/live.py --seconds 30 [--out live.json]
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
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import xml.etree.ElementTree as ET

import numpy as np

from mitsonar.devices.ping360.head import Ping360Settings

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HARBOUR = os.path.join(ROOT, "scenes_xml", "harbour.xml")


def start(*args):
    """``mitsonar live`` in a process; returns (process, its first lines up to the serving one)."""
    env = dict(os.environ)
    env.pop("MITSONAR_DEBUG", None)
    proc = subprocess.Popen([sys.executable, "-m", "mitsonar", "live", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)
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


def summarise(name, rows, seconds, summary, **extra):
    return {"case": name, "pings": len(rows), "seconds": round(seconds, 2),
            "pings_per_s": round(len(rows) / seconds, 2) if seconds else None,
            "latency_ms": percentiles(rows, "latency_ms"), "render_ms": percentiles(rows, "render_ms"),
            "budget_ms": percentiles(rows, "budget_ms"), "paths": percentiles(rows, "paths"),
            "relative_error": percentiles(rows, "error"), "summary": summary, **extra}


def scene_range():
    """The harbour's mechanical head: range_max and bins."""
    root = ET.parse(HARBOUR).getroot()
    s = next(e for e in root.iter("sensor") if e.get("id") == "sonar")
    val = {c.get("name"): c.get("value") for c in s}
    return float(val["range_max"]), int(val["n_bins"])


def micron(seconds, tmp):
    from mitsonar.devices.micron.driver import MicronSonar
    from mitsonar.devices.micron.seanet import HeadSettings

    records = os.path.join(tmp, "micron.csv")
    proc, text = start(HARBOUR, "--head", "micron", "--sensor", "sonar", "--records", records)
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
    return summarise("micron", read_records(records), dt, summary, scanlines_read=n)


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


def ping360(seconds, tmp, pose_rate=None, rss=None):
    records = os.path.join(tmp, "ping360.csv")
    extra = ["--pose-url", "udp://127.0.0.1:0"] if pose_rate else []
    proc, text = start(HARBOUR, "--head", "ping360", "--sensor", "sonar", "--port-url", "udp://127.0.0.1:0",
                       "--records", records, *extra)
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
    return summarise("ping360", read_records(records), dt, summary, replies=n)


def multibeam(seconds, tmp, beams=256, rate=10.0):
    root = ET.parse(HARBOUR).getroot()
    mb = next(e for e in root.iter("sensor") if e.get("id") == "multibeam")
    el = {c.get("name"): c for c in mb}
    step = float(el["bearing_step"].get("value")) * int(el["n_pings"].get("value")) / beams
    el["n_pings"].set("value", str(beams))
    el["bearing_step"].set("value", repr(step))
    scene = os.path.join(tmp, "harbour_mb256.xml")
    ET.ElementTree(root).write(scene)
    records = os.path.join(tmp, "multibeam.csv")
    proc, _ = start(scene, "--ping-rate", str(rate), "--records", records)
    t0 = time.monotonic()
    time.sleep(seconds)
    dt = time.monotonic() - t0
    summary = stop(proc)
    rows = read_records(records)
    skipped = int(summary.split(" late frames skipped")[0].rsplit(" ", 1)[1]) if "late frames skipped" in summary else 0
    return summarise(f"multibeam{beams}", rows, dt, summary, rate_hz=rate, frames_skipped=skipped)


def oculus(seconds, tmp, beams=512, rate=10.0, range_m=10.0, pose_rate=20.0):
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
                       "--status-port", str(status_port), "--pose-url", "udp://127.0.0.1:0", "--records", records)
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
    return summarise(f"oculus{beams}", read_records(records), dt, summary, rate_hz=rate, range_m=range_m,
                     pose_rate_hz=pose_rate, frames_read=frames)


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
    result = ping360(seconds, tmp, pose_rate=50.0, rss=rss)
    t = np.array([r[0] for r in rss]) - rss[0][0]
    m = np.array([r[1] for r in rss])
    after = t >= warmup
    slope = float(np.polyfit(t[after] / 60.0, m[after], 1)[0]) if after.sum() >= 2 else math.nan
    k = int(np.argmax(after)) if after.any() else len(m) - 1
    result.update(case="soak", pose_rate_hz=50.0, rss_mb={
        "start": round(float(m[0]), 1), "after_warmup": round(float(m[k]), 1), "end": round(float(m[-1]), 1),
        "slope_mb_per_min_after_warmup": round(slope, 3), "warmup_s": warmup, "samples": len(m)})
    return result


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=30.0, help="seconds per case (default 30)")
    ap.add_argument("--soak", type=float, nargs="?", const=600.0, default=None, metavar="SECONDS",
                    help="soak instead: poses at 50 Hz and brping pinging for SECONDS (default 600)")
    ap.add_argument("--warmup", type=float, default=60.0, help="soak: seconds before the RSS slope (default 60)")
    ap.add_argument("--cases", default="micron,ping360,multibeam256", help="comma-separated cases")
    ap.add_argument("--out", default=None, help="also write the JSON here")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        if args.soak is not None:
            result = {"benchmark": "live soak", "cpus": os.cpu_count(), **soak(args.soak, args.warmup, tmp)}
        else:
            cases = {"micron": micron, "ping360": ping360, "multibeam256": multibeam, "oculus512": oculus}
            result = {"benchmark": "live", "cpus": os.cpu_count(), "scene": "scenes_xml/harbour.xml",
                      "cases": [cases[c](args.seconds, tmp) for c in args.cases.split(",")]}
    text = json.dumps(result, indent=1)
    print(text)
    if args.out:
        with open(args.out + ".part", "w") as f:
            f.write(text + "\n")
        os.replace(args.out + ".part", args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
