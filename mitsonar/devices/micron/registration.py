"""The Tritech Micron as `mitsonar.devices.registry` knows it: ``--head micron``, the default head,
and the head of every raw log without a ``head`` field (SeaNet logs).

Imports its codec, driver and virtual head only when asked for them.
"""
from __future__ import annotations

from mitsonar.acoustics.water import SOUND_SPEED
from mitsonar.devices.head import Head

__all__ = ["MicronHead", "HEAD"]


class MicronHead(Head):
    name = "micron"
    description = "Tritech Micron (SeaNet)"
    log_tag = None
    protocol = "SeaNet"
    packet = "SeaNet packet"
    ping_word = "scanlines"
    serves = "SeaNet scanlines"
    options = (("passive", "--passive"), ("no_reboot", "--no-reboot"), ("bit_depth", "--bit-depth"),
               ("no_dst", "--no-dst"))

    # ---- parts ----

    def parser(self, nibble_order: str | None = None):
        from mitsonar.devices.micron.seanet.constants import DEFAULT_NIBBLE_ORDER
        from mitsonar.devices.micron.seanet.stream import StreamParser
        return StreamParser(nibble_order=nibble_order or DEFAULT_NIBBLE_ORDER)

    def driver(self):
        from mitsonar.devices.micron.driver import MicronSonar
        return MicronSonar

    def virtual(self):
        from mitsonar.devices.micron.virtual import VirtualMicron
        return VirtualMicron

    def assembler(self, settings, **kwargs):
        """A `ScanAssembler` at ``settings.sound_speed`` snapping to ``settings`` (``kwargs``:
        ``revisit``, ``max_turns``)."""
        from mitsonar.devices.micron.assembler import ScanAssembler
        return ScanAssembler(settings.sound_speed, settings=settings, **kwargs)

    def is_command(self, message) -> bool:
        from mitsonar.devices.micron.seanet.messages import HeadCommand
        return isinstance(message, HeadCommand)

    def usable(self, message, command) -> bool:
        from mitsonar.devices.micron.seanet.messages import HeadData
        from mitsonar.devices.micron.seanet.settings import ping_problem
        return isinstance(message, HeadData) and ping_problem(message, command) is None

    # ---- actions ----

    def settings(self, args=None):
        from mitsonar.devices.micron.seanet.settings import HeadSettings
        kw = {}
        for dest, name in (("range", "range"), ("n_bins", "n_bins"), ("sound_speed", "sound_speed"),
                           ("step", "step_size"), ("bit_depth", "bit_depth")):
            if getattr(args, dest, None) is not None:
                kw[name] = getattr(args, dest)
        return HeadSettings(**kw)

    def serve(self, scan, args) -> int:
        from mitsonar.devices.micron.virtual import serve
        return serve(scan, args.port_url, args.seconds, baudrate=args.baud, realtime=not args.fast,
                     dst=not args.no_dst)

    def record(self, args, settings) -> dict:
        from mitsonar.devices.micron.driver import record
        if args.passive:
            return record(args.port, args.output, args.seconds, baudrate=args.baud, settings=settings,
                          passive=True)
        return record(args.port, args.output, args.seconds, scans=args.scans, pings=args.pings,
                      baudrate=args.baud, settings=settings, reboot=not args.no_reboot,
                      timeout=args.timeout, boot_timeout=args.timeout)

    def replay(self, path, meta: dict, records: list, *, sound_speed=None, pose=None, partial=False,
               nibble_order: str | None = None, revisit: bool | None = None, max_turns: int | None = None,
               **options) -> list:
        """`Head.replay` of a SeaNet log: scanlines count once an mtHeadCommand was sent and
        when they match the last one sent, as `MicronSonar` takes them. ``nibble_order``,
        ``revisit``, ``max_turns``: default the log's."""
        from mitsonar.devices.micron.assembler import ScanAssembler
        from mitsonar.devices.micron.seanet.settings import SOUND_SPEED_ALLOWED, HeadSettings, sound_speed_ok
        from mitsonar.devices.recording import assemble_log
        c = sound_speed or meta.get("sound_speed") or SOUND_SPEED
        if not sound_speed_ok(c):
            raise ValueError(f"{path}: the log's sound_speed = {c!r} is out of range: allowed "
                             f"{SOUND_SPEED_ALLOWED} (pass sound_speed)")
        c = float(c)
        nib = nibble_order or meta.get("nibble_order")
        settings = None
        if isinstance(meta.get("settings"), dict):
            try:
                settings = HeadSettings(**meta["settings"])
            except (TypeError, ValueError):
                settings = None
        if settings is not None and sound_speed is not None:
            settings = None    # a different sound speed changes the range window: no snapping
        asm = ScanAssembler(c, revisit=meta.get("revisit", True) if revisit is None else revisit,
                            max_turns=int(meta.get("max_turns", 3) if max_turns is None else max_turns),
                            settings=settings)
        return assemble_log(path, meta, records, asm, self.parser(nib), self.parser(nib),
                            self.is_command, self.usable, pose, partial, self.packet)


HEAD = MicronHead()
