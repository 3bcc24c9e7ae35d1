"""Multibeam frames at their ping period (``mitsonar live SCENE`` without ``--head``).

`FrameLoop` renders the scene's whole frame (every receive beam, `mitsonar.live.heads.PingRenderer`
with no bearing) at the times ``t0 + k / rate``, each from the vehicle's pose at its own time,
with ``1 / rate`` seconds as its budget, and hands it to each callable of ``on_frame`` as
``on_frame(t_ns, vehicle_pose, mount, scan)`` (``t_ns``: the frame's time, nanoseconds of the
Unix clock; ``vehicle_pose``: 4x4 vehicle in the world; ``mount``: 4x4 sensor on the vehicle;
``scan``: the frame, a `Scan` of one row per beam). A frame is late when its time has passed;
when a render (or a consumer) takes longer than a period, the frames whose time is more than
one period past are skipped and counted, never queued: the loop always renders the newest frame
due. Its latency (frame time to the consumers done) goes to the renderer's log.
"""
from __future__ import annotations

import math
import sys
import threading
import time
from collections import Counter

__all__ = ["FrameLoop"]


class FrameLoop:
    """Render frames at ``rate`` Hz in a thread until `stop` (module doc).

    ``stats``: ``frames`` published, ``late frames skipped``, ``consumer errors``; ``due``: the
    frames whose time came (published or skipped) by the loop's last look at the clock.
    """

    def __init__(self, renderer, rate: float, on_frame=(), *, out=None):
        if not (isinstance(rate, (int, float)) and math.isfinite(rate) and rate > 0):
            raise ValueError(f"--ping-rate {rate!r}: expected a positive number of frames per second")
        self.renderer, self.rate = renderer, float(rate)
        self.period = 1.0 / self.rate
        self.on_frame = list(on_frame)
        self.out = sys.stderr if out is None else out
        self.stats: Counter = Counter()
        self.due = 0
        self._stop = threading.Event()
        self._thread = None
        self.t0 = None
        self._said = set()

    def start(self) -> "FrameLoop":
        if self._thread is None:
            self._stop.clear()
            self.t0 = time.monotonic()
            self._thread = threading.Thread(target=self._run, name="FrameLoop", daemon=True)
            self._thread.start()
        return self

    def stop(self, timeout: float = 30.0) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None

    def _run(self) -> None:
        k = 0
        while not self._stop.is_set():
            now = time.monotonic()
            newest = int(math.floor((now - self.t0) / self.period))
            if newest < k:
                self._stop.wait(self.t0 + k * self.period - now)
                continue
            self.due = newest + 1
            if newest > k:          # frames k .. newest - 1 are more than a period late
                self.stats["late frames skipped"] += newest - k
                self.renderer.log.skipped += newest - k
            try:
                self.frame(newest, self.t0 + newest * self.period)
            except Exception as e:      # noqa: BLE001 - a bad frame is said, the loop goes on
                self.stats["internal errors"] += 1
                self._say(f"frame: {type(e).__name__}: {e}")
            k = newest + 1

    def frame(self, index: int, when: float) -> None:
        """Render frame ``index`` at ``when`` (``time.monotonic``), publish it, log its record."""
        r = self.renderer
        scan = r.render(None, when, self.period)
        record = r.last_record
        record["ping"] = int(index)
        t_ns = int(round(record["t"] * 1e9))
        for consumer in self.on_frame:
            try:
                consumer(t_ns, r.last_vehicle, r.mount, scan)
            except Exception as e:      # noqa: BLE001 - one consumer's failure stops no other
                self.stats["consumer errors"] += 1
                self._say(f"frame consumer {getattr(consumer, '__name__', consumer)!s}: {e}")
        self.stats["frames"] += 1
        r.finish(record)

    def _say(self, text: str) -> None:
        key = text.split(":")[0]
        if key not in self._said:
            self._said.add(key)
            print(f"mitsonar live: warning: {text} (said once)", file=self.out, flush=True)
