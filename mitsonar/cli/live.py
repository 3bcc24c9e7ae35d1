"""``mitsonar live SCENE.xml``: a head in a loop with a vehicle (`mitsonar.live.heads`).

Each ping the client asks for is rendered when it fires, from the vehicle's pose at that time:
poses arrive as UDP datagrams on ``--pose-url`` (`mitsonar.live.poses`), or come from a
``--trajectory`` replayed in real time. Without ``--head``, a scene with a multibeam publishes
its whole frames at ``--ping-rate`` (`mitsonar.live.framing`). Each ping takes the paths that
fit its budget (the head's ping period, or ``--budget-ms``; ``--spp`` fixes them instead) and is
recorded (`mitsonar.live.realtime`; ``--records FILE.csv|.jsonl``). Runs until ``--seconds``
or SIGINT/SIGTERM (exit 0, ports and files closed), then prints what it did (and on SIGUSR1).
``--foxglove``, ``--mcap``, ``--dds``: each ping (or frame) also goes to Foxglove, an MCAP file, ROS 2
over DDS (`mitsonar.live.outputs`). Exit codes as `mitsonar.cli.serial`.
"""
from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from pathlib import Path

from mitsonar.cli.serial import _guard, _head, _positive

__all__ = ["add_subcommands", "cmd_live"]


def _frame_mode(args, scene_path) -> bool:
    """True when the session publishes multibeam frames: no ``--head`` and a multibeam in the
    scene (the first sensor whose rows fire as one frame); None when ``--sensor`` names the
    sensor (its kind decides once the scene is loaded); False with a ``--head``."""
    if args.head is not None:
        return False
    from mitsonar.live.heads import scene_kinds

    if args.sensor is not None:
        return None             # decided by the named sensor's kind once the scene is loaded
    return any(k.transmit_fan for k in scene_kinds(str(scene_path)))


def _live(args) -> int:
    scene_path = Path(args.scene)
    if not scene_path.is_file():
        raise FileNotFoundError(f"scene file not found: {scene_path}")
    if args.spp is not None and args.budget_ms is not None:
        raise ValueError("--spp (fixed paths per ping) and --budget-ms (paths fitted to a time budget): give one")
    frames = _frame_mode(args, scene_path)       # True, False, or None: --sensor's kind decides
    if frames:
        _refuse_head_flags(args, scene_path)
    elif args.ping_rate is not None and frames is False:
        _refuse_ping_rate(args, scene_path)
    if args.head is None and frames is False:
        from mitsonar.devices import registry
        args.head = registry.DEFAULT
    head = _head(args) if args.head is not None else None
    from mitsonar.live.heads import (LIVE_HEADS, PingRenderer, PoseReceiver, SceneObjects, live_scene, pose_bounds,
                                       pose_socket)
    from mitsonar.live.poses import PoseBuffer, TrajectoryReplay
    from mitsonar.live.realtime import PingLog, check_records_path
    if head is not None and head.name not in LIVE_HEADS:
        raise ValueError(f"--head {head.name}: no live version (live heads: {', '.join(LIVE_HEADS)})")
    sources = [f for f, v in (("--pose-url", args.pose_url), ("--trajectory", args.trajectory),
                              ("--mavlink", args.mavlink)) if v]
    if len(sources) > 1:
        raise ValueError(f"{' and '.join(sources)} are {len(sources)} sources of poses: give one")
    from mitsonar.cli.common import check_counts, sensor_of
    from mitsonar.devices.micron.seanet.settings import require_mechanical
    check_counts(args, ValueError)
    if args.records is not None:
        check_records_path(args.records)
    if args.mavlink:
        import importlib.util
        if importlib.util.find_spec("pymavlink") is None:
            raise ValueError("--mavlink needs the pymavlink package (pip install 'mitsonar[live]')")
    trajectory = None
    if args.trajectory:
        from mitsonar.geometry.trajectory import Trajectory
        trajectory = Trajectory.from_tum(args.trajectory)
    sock = pose_socket(args.pose_url) if args.pose_url else None     # a bad URL fails before the load
    log = loop = live = outputs = None
    try:
        if head is not None:
            head.check_serve(args)
        outputs = _outputs(args)                      # a bad flag fails before the load, too
        scene = live_scene(str(scene_path))
        sonar = _frame_sensor(scene, args) if frames is not False else sensor_of(scene, args)
        if frames is None:          # --sensor named it: a multibeam publishes frames, else a head
            frames = bool(sonar.sonar_kind.transmit_fan)
            if frames:
                _refuse_head_flags(args, scene_path)
            else:
                if args.ping_rate is not None:
                    _refuse_ping_rate(args, scene_path)
                from mitsonar.devices import registry
                args.head = registry.DEFAULT
                head = _head(args)
                head.check_serve(args)
        if not frames and head.frames:
            if not sonar.sonar_kind.fan_frame:
                import mitsonar.kinds as kinds
                raise ValueError(f"live {scene_path.name}: --head {head.name} is a multibeam head; a "
                                 f"{sonar.sonar_kind.name!r} sonar (kind must be {kinds.which('fan_frame')}) "
                                 f"has no {head.serves} to serve")
        elif not frames:
            require_mechanical(sonar, f"live {scene_path.name}", f"no {head.serves} to serve")
        buffer = PoseBuffer(bounds=pose_bounds(scene)) if (sock is not None or args.mavlink) else None
        log = PingLog(args.records) if args.records else PingLog()
        budget = None if args.budget_ms is None else args.budget_ms * 1e-3
        renderer = PingRenderer(scene, sonar, buffer, spp=args.spp, seed=args.seed, budget=budget, log=log,
                                outputs=outputs)
        if frames:
            from mitsonar.live.framing import FrameLoop
            rate = args.ping_rate
            if rate is None:
                period = float(getattr(sonar, "ping_period", 0.0) or 0.0)
                rate = 1.0 / period if period > 0 else 10.0
            renderer.warm()
            # the renderer hands each frame to the outputs; on_frame: any further consumers
            loop = FrameLoop(renderer, rate, on_frame=[])
        else:
            kw = {"baudrate": args.baud, "realtime": not args.fast}
            if "no_dst" in {dest for dest, _ in head.options}:     # a head that can be a pre-DST Micron
                kw["dst"] = not args.no_dst
            for dest in ("model", "status_port"):          # an Oculus's model and status port
                if dest in {d for d, _ in head.options} and getattr(args, dest, None) is not None:
                    kw[dest] = getattr(args, dest)
            if hasattr(head, "live_geometry"):      # a head rendering each fire message's geometry (Oculus)
                kw["geometry"] = head.live_geometry(str(scene_path), getattr(args, "sensor", None), sonar)
            live = LIVE_HEADS[head.name]()(renderer, args.port_url, **kw)
    except BaseException:
        if sock is not None:
            sock.close()
        if log is not None:
            log.discard()
        if outputs is not None:
            outputs.discard()
        raise
    receiver = None
    if sock is not None:
        receiver = PoseReceiver(sock, buffer, objects=SceneObjects(scene, renderer.lock).move).start()
    if trajectory is not None:
        renderer.poses = TrajectoryReplay(trajectory)
    mav = None
    if args.mavlink:
        from mitsonar.live.mavlink import MavlinkReceiver
        try:
            mav = MavlinkReceiver(args.mavlink, buffer).start()
        except BaseException:
            if receiver is not None:
                receiver.stop()
            log.discard()
            if outputs is not None:
                outputs.discard()
            raise
    stop = threading.Event()
    previous = {s: signal.signal(s, lambda *_: stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
    if hasattr(signal, "SIGUSR1"):        # the summary so far, on demand (kill -USR1 PID)
        previous[signal.SIGUSR1] = signal.signal(
            signal.SIGUSR1, lambda *_: print(_summary(renderer, receiver, mav, loop, live), flush=True))
    try:
        with (loop_running(loop) if loop is not None else live):
            if receiver is not None:
                print(f"poses on {receiver.url}", flush=True)
            if mav is not None:
                print(f"MAVLink poses on {mav.address}", flush=True)
            for o in (outputs.outputs if outputs is not None else ()):
                print(_said(o), flush=True)
            if loop is not None:
                print(f"live {_sensor_name(sonar)} at {loop.rate:g} Hz", flush=True)
            else:
                label = head.description.split(" (")[0].split()[-1]
                print(f"live {label} on {live.port}", flush=True)
            end = None if args.seconds is None else time.monotonic() + args.seconds
            while not stop.is_set() and (end is None or time.monotonic() < end):
                stop.wait(0.05 if end is None else max(0.0, min(0.05, end - time.monotonic())))
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
        if receiver is not None:
            receiver.stop()
        if mav is not None:
            mav.stop()
        log.close()
        if outputs is not None:
            outputs.close()
    print(_summary(renderer, receiver, mav, loop, live) + (f"; {outputs.summary()}" if outputs is not None else ""),
          flush=True)
    return 0


def _sensor_name(sonar) -> str:
    """The banner's name of a frame sensor: its kind, then its XML id unless that only repeats the
    kind (harbour.xml's multibeam has the id ``multibeam``) or is empty."""
    kind, name = sonar.sonar_kind.name, sonar.id()
    return kind if not name or name.lower() == kind.lower() else f"{kind} {name}"


def _outputs(args):
    """The `LiveOutputs` that --foxglove, --mcap and --dds ask for (None: none)."""
    if args.foxglove is None and args.mcap is None and args.dds is None:
        return None
    from mitsonar.live.outputs import open_outputs
    return open_outputs(foxglove=args.foxglove, mcap=args.mcap, dds=args.dds, force=args.force)


def _said(output) -> str:
    """The line saying where an output is: ``foxglove on ws://...``, ``recording to FILE``, ``dds on ...``."""
    if hasattr(output, "url"):
        return f"foxglove on {output.url}"
    if hasattr(output, "path"):
        return f"recording to {output.path}"
    return f"ROS 2 topics on DDS domain {output.domain}"


def _whole_in(lo: int, hi: int, what: str):
    """An argparse type: a whole number from ``lo`` to ``hi``; else ``expected WHAT, got TEXT`` (``what`` may name {lo} and {hi})."""
    def parse(text):
        try:
            v = int(text)
        except ValueError:
            v = lo - 1
        if not lo <= v <= hi:
            raise argparse.ArgumentTypeError(f"expected {what.format(lo=lo, hi=hi)}, got {text!r}")
        return v
    return parse


_port = _whole_in(0, 65535, "a TCP port from {lo} to {hi} (0: any free one)")
_domain = _whole_in(0, 232, "a DDS domain id from {lo} to {hi}")


def _refuse_ping_rate(args, scene_path) -> None:
    if args.head is not None:
        raise ValueError("--ping-rate is for multibeam frames (no --head); a head pings when its client asks")
    raise ValueError(f"--ping-rate is for multibeam frames; {scene_path.name}'s sensor is a mechanical head, "
                     "which pings when its client asks")


def _refuse_head_flags(args, scene_path) -> None:
    for dest, flag in (("port_url", "--port-url"), ("fast", "--fast"), ("no_dst", "--no-dst"), ("baud", "--baud"),
                       ("model", "--model"), ("status_port", "--status-port")):
        if getattr(args, dest) not in (None, False):
            raise ValueError(f"{flag} is for a head (--head micron|ping360|oculus); {scene_path.name}'s "
                             "multibeam publishes frames at --ping-rate without one")


class loop_running:  # noqa: N801 - a context manager, named for its use
    """``with loop_running(loop):`` runs a `mitsonar.live.framing.FrameLoop` for the block."""

    def __init__(self, loop):
        self.loop = loop

    def __enter__(self):
        return self.loop.start()

    def __exit__(self, *exc):
        self.loop.stop()


def _frame_sensor(scene, args):
    """``--sensor``'s sensor, else the scene's first multibeam (`_frame_mode` found one)."""
    from mitsonar.cli.common import sensor_of
    if args.sensor is not None:
        return sensor_of(scene, args)
    for s in scene.sensors():
        if getattr(getattr(s, "sonar_kind", None), "transmit_fan", False):
            return s
    raise ValueError(f"{args.scene}: no multibeam sensor to publish frames of")


def _summary(renderer, receiver, mav, loop=None, head=None) -> str:
    """One line: pings rendered, render time percentiles, latency, paths and error percentiles,
    frames published and skipped, what the head served (``head.summary()``: an Oculus's pings
    and the ping slots it skipped, late or for a client behind), poses applied and dropped by
    reason."""
    line = renderer.summary()
    if loop is not None:
        line += f"; {loop.stats['frames']} frames published of {loop.due} due"
    served = head.summary() if head is not None else ""
    if served:
        line += f"; head: {served}"
    if receiver is not None:
        st = receiver.stats
        moved = f", {st['objects']} object moves" if st["objects"] else ""
        line += f"; {st['poses']} poses applied{moved}, {st['dropped']} datagrams dropped" + _reasons(receiver)
    if mav is not None:
        line += f"; {mav.stats['poses']} MAVLink poses, {mav.stats['dropped']} dropped" + _reasons(mav)
    return line


def _reasons(source) -> str:
    """`` (N reason, ...)`` of a pose source's drops, empty without any."""
    reasons = ", ".join(f"{n} {r}" for r, n in sorted(source.drops.counts.items()))
    return f" ({reasons})" if reasons else ""


def cmd_live(args) -> int:
    """``mitsonar live SCENE.xml --head micron|ping360 [--pose-url udp://127.0.0.1:PORT]``."""
    return _guard("live", _live, args)


def add_subcommands(subparsers) -> None:
    from mitsonar.cli.common import add_force, add_output, add_sensor
    from mitsonar.devices import registry
    p = subparsers.add_parser(
        "live", help="a live head or multibeam: pings rendered when they fire, from the vehicle's pose then",
        description="Serve the scene's sonar as a Micron or a Ping360 (as virtual-sonar) but render each "
                    "ping the client asks for when it fires, from the vehicle pose at that time: poses "
                    "arrive as JSON datagrams {\"t\", \"position\", \"orientation\"} on --pose-url "
                    "({\"object\": ID, ...} moves the scene's shape ID) "
                    "(the sensor's to_world is the mount on the vehicle: x forward, y port, z up), or "
                    "from a --trajectory replayed in real time. Without --head, a scene with a multibeam "
                    "renders its whole frames at --ping-rate, each at the pose at its time; a frame more "
                    "than one period late is skipped and counted, never queued. Real time: each ping "
                    "renders as many paths as fit its budget (the head's ping period, or --budget-ms), "
                    "from the time per path measured on the pings before; --spp fixes the paths instead. "
                    "Each ping's paths, estimated relative error (measured on the scene at start at 16 to "
                    "4096 paths, interpolated) and latency (pose time to last byte written, or frame published) are "
                    "recorded (--records). Prints 'poses on URL' and 'live HEAD on PORT' (or 'live "
                    "multibeam ID at RATE Hz', the sensor's id left out when it only repeats the kind), "
                    "serves until --seconds or SIGINT/SIGTERM, then a "
                    "summary line (also on SIGUSR1): latency, paths and error p50/p95/p99 (an Oculus head adds "
                    "its pings and the ping slots it skipped, late or for a client behind). --foxglove, "
                    "--mcap and --dds send each ping (or frame) also to Foxglove, an MCAP file and ROS 2 "
                    "over DDS.")
    p.add_argument("scene", metavar="SCENE.xml", help="Mitsuba scene with a mechanical or multibeam `sonar` sensor")
    p.add_argument("--head", choices=registry.names(), default=None,
                   help="which head to be: micron (SeaNet), ping360 (ping-protocol) or oculus (an Oculus "
                        "multibeam on TCP, its pings rendered when they fire); default: the scene's "
                        "multibeam publishes frames, else micron")
    p.add_argument("--port-url", default=None, metavar="URL",
                   help="where to serve, as virtual-sonar: a pseudo-terminal (default), socket://HOST:PORT, "
                        "udp://127.0.0.1:PORT (Ping360)")
    p.add_argument("--pose-url", default=None, metavar="URL",
                   help="read vehicle poses here: udp://127.0.0.1:PORT (loopback only; port 0 picks one)")
    p.add_argument("--trajectory", default=None, metavar="FILE.tum",
                   help="replay this trajectory in real time as the vehicle's poses (a demo without a vehicle)")
    p.add_argument("--mavlink", default=None, metavar="URL",
                   help="read the vehicle's LOCAL_POSITION_NED and ATTITUDE_QUATERNION from this pymavlink "
                        "connection (udpin:127.0.0.1:14550, a serial port; NED/FRD turned to ENU/FLU); "
                        "needs pymavlink (the live extra)")
    p.add_argument("--spp", type=_positive(int), default=None,
                   help="paths of every ping (fixed); default: as many as fit each ping's budget")
    p.add_argument("--budget-ms", type=_positive(float), default=None, metavar="MS",
                   help="render time each ping may take (default: the head's ping period: its listening "
                        "time, transmit and motor step; a frame's period)")
    p.add_argument("--ping-rate", type=_positive(float), default=None, metavar="HZ",
                   help="multibeam frames per second (default: 1 / the sensor's ping_period)")
    add_output(p, "--records", default=None, metavar="FILE.csv|FILE.jsonl",
                   help="write one line per ping: ping, t, pose_time, bearing, paths, error, render_ms, "
                        "latency_ms, budget_ms (written as FILE.part, renamed at the end)")
    p.add_argument("--seed", type=int, default=0, help="seed of ping 0; ping k uses seed + k (default 0)")
    p.add_argument("--baud", type=_positive(int), default=None, help="baud rate of the timing model")
    p.add_argument("--fast", action="store_true", help="answer as soon as rendered (no timing model)")
    p.add_argument("--no-dst", action="store_true", help="behave as a pre-DST Micron (--head micron)")
    p.add_argument("--model", choices=("M750d", "M1200d", "M3000d"), default=None,
                   help="which Oculus to be (--head oculus; default M1200d)")
    p.add_argument("--status-port", type=int, default=None, metavar="PORT",
                   help="UDP port of the Oculus status broadcast (--head oculus; default 52102)")
    p.add_argument("--seconds", type=_positive(float), default=None, help="stop after T seconds")
    p.add_argument("--foxglove", type=_port, nargs="?", const=8765, default=None, metavar="PORT",
                   help="serve the sonar picture, the raw pings, the frames (map, base_link, sonar) and the "
                        "vehicle pose to Foxglove over WebSocket on ws://127.0.0.1:PORT (default 8765; 0 picks "
                        "one); needs foxglove-sdk (the live extra)")
    add_output(p, "--mcap", default=None, metavar="FILE.mcap",
                   help="record the same channels into this MCAP file (complete when the session stops: "
                        "--seconds, SIGINT, SIGTERM); needs foxglove-sdk (the live extra)")
    p.add_argument("--dds", type=_domain, nargs="?", const=0, default=None, metavar="DOMAIN",
                   help="publish the same topics as ROS 2 messages over DDS on this domain (default 0), "
                        "so ROS 2 nodes subscribe without a bridge; needs cyclonedds (the live extra)")
    add_sensor(p)
    add_force(p)
    p.set_defaults(func=cmd_live)
