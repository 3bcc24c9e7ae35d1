"""What a serial head is to mitsonar: `Head`, the base of every head's entry in
`mitsonar.devices.registry` (``mitsonar/devices/<head>/registration.py`` defines ``HEAD``).

Its defaults drive, record and replay a head through its parts alone (codec parser, driver,
virtual head, assembler), so a new head need define little more than those.
"""
from __future__ import annotations

__all__ = ["Head"]


class Head:
    """One kind of serial head: its name, its parts, and what the command line does with it.

    Class attributes (a subclass sets them)
    ---------------------------------------
    ===========  ===================================================================
    name         ``--head NAME``, the registry's key
    description  one line: what the head is
    log_tag      the raw log header's ``head`` for its logs (None: no ``head`` field,
                 as SeaNet logs have always been written)
    protocol     what its packets are called in messages ("SeaNet", "ping-protocol")
    packet       one whole unit of the codec, for "bytes that form no whole PACKET"
    ping_word    what `record` counts ("scanlines", "pings")
    serves       what a virtual head serves ("SeaNet scanlines", "Ping360 pings"): a scan
                 it cannot serve "has no SERVES to serve"
    baudrate     default baud rate of its line
    options      ``(dest, flag)`` of the command-line options only this head takes: any
                 other head refuses them in one line
    frames       True for a head whose pings are whole multibeam frames (a kind with a
                 transmit fan, `mitsonar.kinds`); False (default): scanlines of a
                 mechanically scanned head
    ===========  ===================================================================

    Parts (methods, so that a subclass imports its modules only when asked): `parser` (a new
    stream parser of the codec: ``feed(bytes) -> [message]``, ``flush()``, ``packets``,
    ``dropped``, ``drop_reasons``), `driver` (the driver class, a
    `mitsonar.devices.transports.LineDriver`), `virtual` (the virtual head class, a
    `mitsonar.devices.transports.ServedHead`), `assembler` (a new scan assembler:
    ``add(message, pose, t) -> Scan | None``, ``finish()``).

    Actions, with defaults built on the parts: `settings` (from command-line arguments),
    `serve` (``virtual-sonar``), `record` (``record``), `replay` (a raw log's scans).
    """

    name: str = ""
    description: str = ""
    log_tag: str | None = None
    protocol: str = ""
    packet: str = "packet"
    ping_word: str = "pings"
    serves: str = "pings"
    baudrate: int = 115200
    options: tuple = ()
    frames: bool = False

    def __repr__(self):
        return f"<{type(self).__name__} {self.name!r}>"

    # ---- parts ----

    def parser(self):
        """A new stream parser of the head's codec (one per direction of a log)."""
        raise NotImplementedError(f"head {self.name!r} defines no parser")

    def driver(self):
        """The driver class: ``driver(port, baudrate, settings, pose, start=False, timeout=...)``."""
        raise NotImplementedError(f"head {self.name!r} has no driver")

    def virtual(self):
        """The virtual head class: ``virtual(scan, port_url, baudrate=..., realtime=...)``."""
        raise NotImplementedError(f"head {self.name!r} has no virtual head")

    def assembler(self, settings):
        """A new scan assembler for a head set to ``settings``."""
        raise NotImplementedError(f"head {self.name!r} has no scan assembler")

    def is_command(self, message) -> bool:
        """Is ``message`` (sent to the head) one that asks for pings?"""
        raise NotImplementedError(f"head {self.name!r} cannot replay logs")

    def usable(self, message, command) -> bool:
        """Does ``message`` (from the head) answer ``command`` as the driver takes it?"""
        raise NotImplementedError(f"head {self.name!r} cannot replay logs")

    #: the driver takes one reply per command (else every matching message counts)
    one_reply_per_command: bool = False

    # ---- actions ----

    def settings(self, args=None):
        """The head's settings from command-line arguments (``record``; None: defaults)."""
        raise NotImplementedError(f"head {self.name!r} has no settings")

    def log_settings(self, meta: dict, sound_speed: float | None, path):
        """The settings a log was recorded with (its header ``meta``), at ``sound_speed`` if
        given; raises ValueError naming ``path`` when they are unusable."""
        return self.settings(None)

    def reads_file(self, path) -> bool:
        """Is ``path`` a log of the head's own format (not a `mitsonar.devices.rawlog` raw log),
        which `replay_file` reads? (default: no such format)"""
        return False

    def replay_file(self, path, *, pose=None, partial=False) -> list:
        """The scans of a log of the head's own format (`reads_file`)."""
        raise NotImplementedError(f"head {self.name!r} has no log format of its own")

    def check_serve(self, args) -> None:
        """Fail now, before a render, if `serve` could not open ``args.port_url`` (OSError or
        ValueError naming it)."""
        from mitsonar.devices.transports import check_port
        check_port(args.port_url, args.baud)

    def serve(self, scan, args) -> int:
        """``virtual-sonar``: serve ``scan`` as this head on ``args.port_url`` until
        ``args.seconds`` or Ctrl-C; prints ``virtual NAME on PORT``."""
        head = self.virtual()(scan, args.port_url, baudrate=args.baud, realtime=not args.fast)
        return head.serve(args.seconds, None, f"virtual {self.name}")

    def record(self, args, settings) -> dict:
        """``record``: drive the head on ``args.port`` and log its bytes to ``args.output``
        (`mitsonar.devices.recording.record_driven`); returns its counts."""
        from mitsonar.devices.recording import record_driven
        with self.driver()(args.port, args.baud, settings, None, start=False, timeout=args.timeout) as sonar:
            return record_driven(sonar, args.output, args.seconds, args.scans, args.pings, sonar.start,
                                 self.protocol)

    def replay(self, path, meta: dict, records: list, *, sound_speed=None, pose=None, partial=False,
               **options) -> list:
        """The scans of a log's ``records`` (`mitsonar.devices.rawlog.read_log`), as the driver
        assembled them while recording (`mitsonar.devices.recording.assemble_log`). ``options``
        are head-specific (a head ignores those it does not know)."""
        from mitsonar.devices.recording import assemble_log
        settings = self.log_settings(meta, sound_speed, path)
        return assemble_log(path, meta, records, self.assembler(settings), self.parser(), self.parser(),
                            self.is_command, self.usable, pose, partial, self.packet,
                            once=self.one_reply_per_command)
