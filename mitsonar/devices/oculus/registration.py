"""The Blueprint Subsea Oculus M-series as `mitsonar.devices.registry` knows it: ``--head
oculus``, and the head of raw logs whose header says ``head: oculus``.

Unlike the serial heads it talks Ethernet (TCP 52100 for fire messages and ping results, UDP
52102 for the status broadcast) and is a multibeam: its scans are of kind ``multibeam``
(`frames`). Imports its codec, driver and virtual head only when asked for them.
"""
from __future__ import annotations

from mitsonar.devices.head import Head

__all__ = ["OculusHead", "HEAD"]


class OculusHead(Head):
    name = "oculus"
    description = "Blueprint Subsea M-series Oculus (Ethernet multibeam)"
    log_tag = "oculus"
    protocol = "Oculus"
    packet = "Oculus message"
    ping_word = "pings"
    serves = "Oculus pings"
    frames = True
    options = (("model", "--model"), ("status_port", "--status-port"), ("log", "--log"))

    # ---- parts ----

    def parser(self):
        from mitsonar.devices.oculus.protocol import StreamParser
        return StreamParser()

    def driver(self):
        from mitsonar.devices.oculus.driver import OculusSonar
        return OculusSonar

    def virtual(self):
        from mitsonar.devices.oculus.virtual import VirtualOculus
        return VirtualOculus

    def assembler(self, settings):
        from mitsonar.devices.oculus.head import OculusAssembler
        return OculusAssembler(settings)

    def is_command(self, message) -> bool:
        from mitsonar.devices.oculus.protocol import FireMessage
        return isinstance(message, FireMessage)

    def usable(self, message, command) -> bool:
        from mitsonar.devices.oculus.protocol import PingResult
        return isinstance(message, PingResult) and command.ping_rate != 5

    # ---- actions ----

    def settings(self, args=None):
        """The fire message `record` sends (`mitsonar.devices.oculus.driver.fire_message`)."""
        from mitsonar.devices.oculus.driver import fire_message
        kw = {}
        if getattr(args, "range", None) is not None:
            kw["range"] = args.range
        if getattr(args, "sound_speed", None) is not None:
            kw["speed_of_sound"] = args.sound_speed
        return fire_message(**kw)

    def log_settings(self, meta: dict, sound_speed, path):
        return None

    def reads_file(self, path) -> bool:
        from mitsonar.devices.oculus.logfile import is_oculus_log
        return is_oculus_log(path)

    def replay_file(self, path, *, pose=None, partial=False) -> list:
        """The frames of a ``.oculus`` log (`mitsonar.devices.oculus.logfile.read_scans`)."""
        from mitsonar.devices.oculus.logfile import read_scans
        return read_scans(path, pose)

    def check_serve(self, args) -> None:
        """The address of ``--port-url`` parses and its TCP port can be bound now."""
        import socket

        from mitsonar.devices.oculus.virtual import parse_tcp_url
        host, port = parse_tcp_url(getattr(args, "port_url", None))
        status = getattr(args, "status_port", None)
        if status is not None and not 0 < status <= 65535:
            raise ValueError(f"--status-port {status} is not allowed (1..65535)")
        s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError as e:
            raise OSError(f"--port-url tcp://{host}:{port}: cannot listen there ({e.strerror or e})") from None
        finally:
            s.close()

    def serve(self, scan, args) -> int:
        from mitsonar.devices.oculus.protocol import UDP_PORT
        from mitsonar.devices.oculus.virtual import VirtualOculus, parse_tcp_url
        host, port = parse_tcp_url(getattr(args, "port_url", None))
        status = getattr(args, "status_port", None)
        frames, water = None, None
        if getattr(args, "scene", None) is not None and not isinstance(scan, (list, tuple)):
            # each fire message's geometry rendered from the scene (mitsonar.devices.oculus.scenes)
            from mitsonar.devices.oculus.scenes import SceneFrames
            from mitsonar.sim.render import DEFAULT_SPP
            frames = SceneFrames(args.scene, getattr(args, "sensor", None), bin_width=scan.bin_width,
                                 spp=args.spp or DEFAULT_SPP, seed=args.seed)
            water = frames.water()           # the head's temperature and surface: the scene's
        head = VirtualOculus(scan, model=getattr(args, "model", None) or "M1200d", host=host, tcp_port=port,
                             udp_port=UDP_PORT if status is None else status, realtime=not args.fast,
                             frames=frames, water=water)
        return head.serve(args.seconds, None, "virtual Oculus")

    def live_geometry(self, path: str, sensor, sonar):
        """``mitsonar live``: the scene sensor ``sonar`` (of ``path``, ``--sensor``) at each fire
        message's geometry, ``(mode, n_beams, range) -> sensor``, range lines as wide as its bins
        (`mitsonar.devices.oculus.scenes.SceneFrames.sensor_at`)."""
        from mitsonar.devices.oculus.scenes import SceneFrames
        return SceneFrames(path, sensor, bin_width=sonar.bin_width).sensor_at

    def record(self, args, settings) -> dict:
        """``record``: drive the Oculus at ``args.port`` (``tcp://HOST:PORT``, ``HOST``; ``auto``:
        found by its status broadcast) and log to ``args.output``: a ``.oculus`` log (the ping
        results as sent) when the name ends so, else a raw log of every byte."""
        from mitsonar.devices.oculus.driver import record, record_oculus
        from mitsonar.devices.oculus.virtual import parse_tcp_url
        host, port = (None, 52100) if args.port == "auto" else parse_tcp_url(args.port, default_port=52100)
        how = record_oculus if str(args.output).endswith(".oculus") else record
        return how(host, args.output, args.seconds, pings=args.pings or args.scans, tcp_port=port,
                   fire=settings, timeout=args.timeout)


HEAD = OculusHead()
