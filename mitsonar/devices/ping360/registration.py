"""The Blue Robotics Ping360 as `mitsonar.devices.registry` knows it: ``--head ping360``, and the
head of raw logs whose header says ``head: ping360``.

Imports its codec, driver and virtual head only when asked for them.
"""
from __future__ import annotations

from mitsonar.acoustics.water import SOUND_SPEED
from mitsonar.devices.head import Head

__all__ = ["Ping360Head", "HEAD"]


class Ping360Head(Head):
    name = "ping360"
    description = "Blue Robotics Ping360 (ping-protocol)"
    log_tag = "ping360"
    protocol = "ping-protocol"
    packet = "ping-protocol message"
    ping_word = "pings"
    serves = "Ping360 pings"
    options = (("gain", "--gain"), ("frequency", "--frequency"), ("transmit_duration", "--transmit-duration"))
    one_reply_per_command = True

    # ---- parts ----

    def parser(self):
        from mitsonar.devices.ping360.protocol import StreamParser
        return StreamParser()

    def driver(self):
        from mitsonar.devices.ping360.driver import Ping360Sonar
        return Ping360Sonar

    def virtual(self):
        from mitsonar.devices.ping360.virtual import VirtualPing360
        return VirtualPing360

    def assembler(self, settings):
        from mitsonar.devices.ping360.head import Ping360Assembler
        return Ping360Assembler(settings)

    def is_command(self, message) -> bool:
        from mitsonar.devices.ping360.protocol import ids
        return message.message_id == ids["transducer"] and bool(message.transmit)

    def usable(self, message, command) -> bool:
        from mitsonar.devices.ping360.head import ping_problem
        from mitsonar.devices.ping360.protocol import ids
        return message.message_id == ids["device_data"] and ping_problem(message, command) is None

    # ---- actions ----

    def settings(self, args=None):
        from mitsonar.devices.ping360.head import GAIN_PRESETS, Ping360Settings
        kw = {}
        for dest, name in (("range", "range"), ("n_bins", "number_of_samples"), ("sound_speed", "sound_speed"),
                           ("step", "step"), ("frequency", "transmit_frequency"),
                           ("transmit_duration", "transmit_duration")):
            if getattr(args, dest, None) is not None:
                kw[name] = getattr(args, dest)
        if getattr(args, "gain", None) is not None:
            kw["gain_setting"] = GAIN_PRESETS[args.gain]
        return Ping360Settings(**kw)

    def log_settings(self, meta: dict, sound_speed, path):
        """The log's `Ping360Settings` at ``sound_speed`` (default the log's, else 1500 m/s)."""
        from mitsonar.devices.ping360.head import LIMITS, Ping360Settings
        lo, hi = LIMITS["sound_speed"]
        c = sound_speed or meta.get("sound_speed") or SOUND_SPEED
        if not (isinstance(c, (int, float)) and lo <= c <= hi):
            raise ValueError(f"{path}: sound_speed = {c!r} is out of range: allowed {lo:g}..{hi:g} m/s")
        try:
            return Ping360Settings(**{**meta.get("settings", {}), "sound_speed": float(c)})
        except (TypeError, ValueError) as e:
            raise ValueError(f"{path}: the log's Ping360 settings are unusable ({e})") from None

    def serve(self, scan, args) -> int:
        import math

        from mitsonar.devices.ping360.virtual import serve
        step = abs(math.degrees(float(scan.bearings[1] - scan.bearings[0]))) if scan.n_pings > 1 else 0.0
        if abs(step - 0.9) > 1e-9:
            print(f"a Ping360 pings every 0.9 deg; the scene's {scan.n_pings} pings are {step:g} deg apart: "
                  f"each angle gets the nearest rendered bearing's ping within half a step, others zeros",
                  flush=True)
        return serve(scan, args.port_url, args.seconds, baudrate=args.baud, realtime=not args.fast)

    def record(self, args, settings) -> dict:
        from mitsonar.devices.ping360.driver import record
        return record(args.port, args.output, args.seconds, scans=args.scans, pings=args.pings,
                      baudrate=args.baud, settings=settings, timeout=args.timeout)


HEAD = Ping360Head()
