"""Command-line subcommands for serial devices: ``virtual-sonar``, ``record``, ``replay``.

Two heads: a Tritech Micron (SeaNet, the default) and a Blue Robotics Ping360 (``--head
ping360``: ping-protocol over a serial line or UDP). ``replay`` reads the head from the log.
Which head does what is asked of `mitsonar.devices.registry` (``--head`` offers its names): this
module knows no head by name.

The main CLI calls `add_subcommands(subparsers)`; each subcommand sets ``func(args) -> int``.
Every failure ends in one line on stderr and a non-zero exit code, never a traceback:

====  ===================================================
0     success (also Ctrl-C on a server or recorder)
1     the command failed (bad file, port, head, render)
2     bad arguments (argparse)
====  ===================================================

Outputs (``record``'s log, ``replay``'s scans) are checked within a second of launch, before
any port is opened or log read (folder exists and is writable, the path is no folder; one that
exists is refused without ``--force``, `mitsonar.cli.common.check_outputs`), and
written under temporary names renamed at the end, so a failure leaves no partial file.
``virtual-sonar`` writes no file.
"""
from __future__ import annotations

import argparse
import os
import re
import sys
import warnings
from pathlib import Path

from mitsonar._checks import first_line

__all__ = ["add_subcommands", "cmd_virtual_sonar", "cmd_record", "cmd_replay"]


def _guard(name: str, fn, args) -> int:
    try:
        return int(fn(args) or 0)
    except KeyboardInterrupt:
        return 0
    except SystemExit as e:                       # argparse-like exits inside helpers
        return int(e.code or 0) if isinstance(e.code, int) else 1
    except BaseException as e:                    # noqa: BLE001 - the CLI must not show tracebacks
        # Mitsuba wraps an exception of a Python plugin into a traceback: its reason is the last line
        print(f"mitsonar {name}: error: {first_line(e, traceback_reason=True)}", file=sys.stderr)
        return 1


def _positive(number_type):
    def conv(text):
        try:
            v = number_type(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a positive {number_type.__name__}, got {text!r}") from None
        if v <= 0:
            raise argparse.ArgumentTypeError(f"expected a positive {number_type.__name__}, got {text!r}")
        return v
    return conv


def _sound_speed(text):
    """--sound-speed of record and replay: the bound a head accepts (seanet.HeadSettings)."""
    from mitsonar.devices.micron.seanet.settings import SOUND_SPEED_ALLOWED, sound_speed_ok
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in {SOUND_SPEED_ALLOWED}, got {text!r}") from None
    if not sound_speed_ok(v):
        raise argparse.ArgumentTypeError(f"{text!r} is out of range: allowed {SOUND_SPEED_ALLOWED}")
    return v


def _check_output(path, suffixes: tuple = ()) -> Path:
    """Refuse an output file that cannot be written, before any slow work, in one line naming it
    (`mitsonar._files.check_output_file`: not a folder, an extension of ``suffixes`` when given, in
    a folder that exists and is writable). Outputs are then written under a temporary name and
    renamed, so this is the only place a bad path shows up."""
    from mitsonar._files import check_output_file

    return Path(check_output_file(os.fspath(path), ValueError, extensions=suffixes))


def _head(args):
    """The head of ``--head`` (`mitsonar.devices.registry`), once the options only other heads
    take are refused in one line, not ignored. Fills in the head's default baud rate."""
    from mitsonar.devices import registry
    head = registry.get(getattr(args, "head", registry.DEFAULT))
    own = {dest for dest, _ in head.options}
    for other in registry.heads():
        for dest, flag in () if other is head else other.options:
            if dest not in own and getattr(args, dest, None) not in (None, False):
                raise ValueError(f"{flag} is for --head {other.name}, not {head.name}")
    if getattr(args, "baud", 0) is None:
        args.baud = head.baudrate
    return head


# ---- virtual-sonar ----

def _virtual_sonar(args) -> int:
    from mitsonar.sim.scene import check_scene_file
    if getattr(args, "log", None) is not None:
        return _virtual_sonar_log(args)
    if args.scene is None:
        raise ValueError("give SCENE.xml to render (or --log LOG with --head oculus)")
    scene_path = Path(args.scene)
    check_scene_file(scene_path)
    head = _head(args)
    import mitsonar
    from mitsonar.cli.common import check_counts, sensor_of
    from mitsonar.devices.micron.seanet.settings import require_mechanical
    check_counts(args, ValueError)
    # A port that cannot be opened fails now, not after the render.
    head.check_serve(args)
    scene = mitsonar.load_scene(str(scene_path))
    sensor = sensor_of(scene, args)      # --sensor, or the first sonar (one warning if several)
    # Refuse before the render, not after it: a multibeam scene can take a while to render.
    if head.frames:
        import mitsonar.kinds as kinds
        if not getattr(kinds.lookup(getattr(sensor, "kind", kinds.DEFAULT)), "fan_frame", False):
            raise ValueError(f"virtual-sonar {scene_path.name}: --head {head.name} is a multibeam head; a "
                             f"{getattr(sensor, 'kind', kinds.DEFAULT)!r} sonar (kind must be "
                             f"{kinds.which('fan_frame')}) has no {head.serves} to serve")
    else:
        require_mechanical(sensor, f"virtual-sonar {scene_path.name}", f"no {head.serves} to serve")
    kw = {"seed": args.seed, "sensor": sensor}
    if args.spp is not None:
        kw["spp"] = args.spp
    scan = mitsonar.render_scan(scene, **kw)
    print(f"rendered {scene_path.name}: {scan.n_pings} pings x {scan.n_bins} bins, "
          f"{scan.range_min:g}..{scan.range_max:g} m", flush=True)
    return head.serve(scan, args)


def _virtual_sonar_log(args) -> int:
    """``virtual-sonar --log LOG``: serve the scans of a log (`mitsonar.devices.recording.replay`)."""
    head = _head(args)          # refuses --log for a head that does not take it
    if args.scene is not None:
        raise ValueError(f"give SCENE.xml or --log LOG, not both (got {args.scene} and {args.log})")
    log = Path(args.log)
    if not log.is_file():
        raise FileNotFoundError(f"--log: log file not found: {log}")
    head.check_serve(args)
    from mitsonar.devices.recording import replay
    scans = replay(log)
    if not scans:
        raise ValueError(f"--log {log}: no ping in the log")
    print(f"read {log.name}: {len(scans)} frames", flush=True)
    return head.serve(scans, args)


def cmd_virtual_sonar(args) -> int:
    """``mitsonar virtual-sonar SCENE.xml [--head ping360]``: render once, serve the scan as a
    Micron (or a Ping360)."""
    return _guard("virtual-sonar", _virtual_sonar, args)


# ---- record ----

def _record(args) -> int:
    _check_output(args.output)
    head = _head(args)
    settings = head.settings(args)
    return _recorded(args, head.record(args, settings), head.ping_word)


def _recorded(args, stats: dict, what: str) -> int:
    dropped = stats.get("bytes_dropped", 0)
    note = f"; {dropped} bytes in formed no whole packet (the log keeps them)" if dropped else ""
    print(f"recorded {stats['bytes_rx']} bytes in, {stats['bytes_tx']} out "
          f"({stats['pings']} {what}{note}) to {args.output}")
    return 0


def cmd_record(args) -> int:
    """``mitsonar record PORT -o log.bin``: drive a head (or listen) and log the raw bytes."""
    return _guard("record", _record, args)


# ---- replay ----

def _replay(args) -> int:
    from mitsonar.scan.io import EXTENSIONS
    from mitsonar._files import StagedFiles
    from mitsonar.devices.rawlog import LogDamageWarning
    from mitsonar.devices.recording import replay
    out = _check_output(args.output, EXTENSIONS)
    log = Path(args.log)
    if not log.is_file():
        raise FileNotFoundError(f"log file not found: {log}")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", LogDamageWarning)
        try:
            scans = replay(log, sound_speed=args.sound_speed, partial=args.partial)
        finally:
            # What was skipped, one line each, before the result or the error it explains.
            for w in caught:
                if issubclass(w.category, LogDamageWarning):
                    print(f"mitsonar replay: warning: {w.message}", file=sys.stderr)
                else:
                    warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    if not scans:
        raise ValueError(f"{log}: no complete scan in the log")
    if args.all:
        # All or nothing: every scan under a temporary name first, renamed once all are written.
        paths = [out.with_name(f"{out.stem}_{k:03d}{out.suffix}") for k in range(len(scans))]
        with StagedFiles() as files:
            for scan, path in zip(scans, paths):
                scan.save(files.temporary(path))
        print(f"{len(scans)} scans from {log} written as {out.stem}_NNN{out.suffix}")
        return 0
    if not -len(scans) <= args.index < len(scans):
        raise ValueError(f"{log}: --index {args.index} but the log holds {len(scans)} scan(s)")
    scans[args.index].save(str(out))       # Scan.save writes a temporary file and renames it
    print(f"scan {args.index % len(scans)} of {len(scans)} from {log} written to {out}")
    return 0


def _replayed(path, args) -> list:
    """What ``replay -o PATH`` would overwrite (`mitsonar.cli.common.add_output`): the file, or
    with ``--all`` the files ``STEM_NNN.EXT`` beside it."""
    from mitsonar.cli.common import existing_file, files_in_folder
    if not args.all:
        return existing_file(path, args)
    stem, ext = os.path.splitext(os.path.basename(path))
    folder = os.path.dirname(path) or "."
    found = files_in_folder(pattern=re.escape(stem) + r"_\d{3,}" + re.escape(ext))(folder, args)
    return [os.path.join(os.path.dirname(path), f) for f in found]


def cmd_replay(args) -> int:
    """``mitsonar replay log.bin -o scan.exr``: turn a raw log into scans."""
    return _guard("replay", _replay, args)


# ---- registration ----

def add_subcommands(subparsers) -> None:
    """Add ``virtual-sonar``, ``record`` and ``replay`` to an argparse subparsers object
    (``--head`` offers the heads of `mitsonar.devices.registry` at this moment)."""
    from mitsonar.devices import registry
    p = subparsers.add_parser(
        "virtual-sonar", help="serve a rendered scene as a Tritech Micron, a Ping360 or an Oculus multibeam",
        description="Render SCENE.xml once and answer the SeaNet protocol with its scan, like a "
                    "Micron on a serial line (--head ping360: ping-protocol, like a Blue Robotics "
                    "Ping360, on a pseudo-terminal or udp://127.0.0.1:PORT; --head oculus: a "
                    "Blueprint Oculus M-series multibeam on TCP 127.0.0.1:52100 with its status on "
                    "UDP 52102). Prints the port to open (e.g. with `mitsonar record`), then serves "
                    "until Ctrl-C.")
    p.add_argument("scene", metavar="SCENE.xml", nargs="?", default=None,
                   help="Mitsuba scene with a `sonar` sensor (none with --log)")
    p.add_argument("--log", default=None, metavar="LOG",
                   help="serve the frames of a log instead of a render (--head oculus: a .oculus log or "
                        "its raw log; ping k is frame k of the log, from the first again at the end)")
    p.add_argument("--head", choices=registry.names(), default=registry.DEFAULT,
                   help="which head to be: a Tritech Micron (SeaNet, default), a Blue Robotics "
                        "Ping360 (ping-protocol; prints 'virtual Ping360 on PORT') or an Oculus "
                        "(a multibeam scene; prints 'virtual Oculus MODEL on tcp://HOST:PORT')")
    p.add_argument("--port-url", default=None, metavar="URL",
                   help="where to serve: a new pseudo-terminal (default), socket://HOST:PORT "
                        "(listen for pyserial socket:// clients), udp://127.0.0.1:PORT (Ping360 "
                        "over UDP, loopback only), or a pyserial URL/device to sit on; --head oculus: "
                        "tcp://HOST:PORT (default tcp://127.0.0.1:52100)")
    p.add_argument("--spp", type=_positive(int), default=None, help="paths per ping (render_scan's default)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the render (default 0)")
    p.add_argument("--baud", type=_positive(int), default=None,
                   help="baud rate of the timing model (default the head's, 115200)")
    p.add_argument("--fast", action="store_true", help="answer at once (no timing model)")
    p.add_argument("--no-dst", action="store_true", help="behave as a pre-DST Micron (--head micron)")
    p.add_argument("--model", choices=("M750d", "M1200d", "M3000d"), default=None,
                   help="which Oculus to be (--head oculus; default M1200d)")
    p.add_argument("--status-port", type=int, default=None, metavar="PORT",
                   help="UDP port of the status broadcast, sent to the served address (--head oculus; "
                        "default 52102)")
    p.add_argument("--seconds", type=_positive(float), default=None, help="stop after T seconds")
    from mitsonar.cli.common import add_force, add_output, add_sensor
    add_sensor(p)
    p.set_defaults(func=cmd_virtual_sonar)

    p = subparsers.add_parser(
        "record", help="log the raw byte stream of a Micron (SeaNet) or Ping360 head",
        description="Start the head on PORT, request scanlines and write every byte in and out "
                    "with timestamps to a raw log (format: mitsonar.devices.rawlog). --passive only "
                    "listens, e.g. on a tap of the head's transmit line. The log is written "
                    "under a temporary name in its folder and renamed at the end (also on "
                    "Ctrl-C); a recording without any packet from the head leaves no file.")
    p.add_argument("port", metavar="PORT", help="serial device or pyserial URL (socket://HOST:PORT, ...); "
                                                "a Ping360 also udp://HOST:PORT; an Oculus tcp://HOST:PORT, "
                                                "HOST, or auto (found by its status broadcast)")
    add_output(p, "-o", "--output", required=True, metavar="LOG",
               help="raw log to write (--head oculus: LOG.oculus writes an Oculus log of its pings)")
    p.add_argument("--head", choices=registry.names(), default=registry.DEFAULT,
                   help="the head on PORT: Tritech Micron (default), Blue Robotics Ping360 or Blueprint Oculus")
    p.add_argument("--seconds", type=_positive(float), default=None, help="stop after T seconds")
    p.add_argument("--scans", type=_positive(int), default=None, help="stop after N complete scans")
    p.add_argument("--pings", type=_positive(int), default=None, help="stop after N scanlines")
    p.add_argument("--baud", type=_positive(int), default=None, help="default the head's (115200)")
    p.add_argument("--passive", action="store_true", help="only listen (needs --seconds)")
    p.add_argument("--no-reboot", action="store_true", help="attach to a running head without mtReBoot")
    p.add_argument("--timeout", type=_positive(float), default=30.0, metavar="S",
                   help="give up when the head sends nothing usable for S seconds: each start-up "
                        "step and each scanline (default 30). A log that got no packet is removed; "
                        "one that did is kept")
    p.add_argument("--range", type=_positive(float), default=None, help="range scale, m (default 12)")
    p.add_argument("--n-bins", type=_positive(int), default=None,
                   help="bins per scanline (default 500; Ping360: samples per ping, 200..1200, default 1200)")
    p.add_argument("--sound-speed", type=_sound_speed, default=None, help="m/s, 1300..1800 (default 1500)")
    p.add_argument("--step", type=_positive(int), default=None,
                   help="motor step in 1/16 gradian (default 32 = 1.8 deg); Ping360: gradians "
                        "(default 1 = 0.9 deg, a divisor of 400)")
    p.add_argument("--bit-depth", type=int, choices=(8, 4), default=None, help="Micron only")
    p.add_argument("--gain", choices=("low", "normal", "high"), default=None,
                   help="Ping360 gain setting (default normal)")
    p.add_argument("--frequency", type=_positive(int), default=None, help="Ping360 kHz, 500..1000 (default 750)")
    p.add_argument("--transmit-duration", type=_positive(int), default=None, metavar="US",
                   help="Ping360 us, 1..1000 (default: 8000 range / c, at least 2.5 sample periods, 5..500)")
    add_force(p)
    p.set_defaults(func=cmd_record)

    p = subparsers.add_parser(
        "replay", help="turn a raw log (Micron or Ping360) into scans",
        description="Assemble the scans of a raw log (as the driver did while recording; the "
                    "log says which head) and save one, or all, with Scan.save (.exr or .npz).")
    p.add_argument("log", metavar="LOG", help="raw log written by `mitsonar record`")
    add_output(p, "-o", "--output", required=True, metavar="SCAN", help="output file (.exr, .npz)",
               existing=_replayed)
    p.add_argument("--index", type=int, default=0, help="which scan to save (default 0; -1 the last)")
    p.add_argument("--all", action="store_true", help="save every scan as OUTPUT_NNN.ext")
    p.add_argument("--sound-speed", type=_sound_speed, default=None,
                   help="m/s, 1300..1800 (default the log's)")
    p.add_argument("--partial", action="store_true", help="also the unfinished scan at the end")
    add_force(p)
    p.set_defaults(func=cmd_replay)
