"""What a live head does with each ping besides answering its client: `LiveOutput`, the interface
of an output (a Foxglove server, an MCAP recording, ROS 2 topics over DDS), and `LiveOutputs`,
which hands each ping to all of them from a thread of its own, so that a slow output never delays
the client's answer.

A ping is ``(t_ns, vehicle, mount, scan)``: ``t_ns`` its time (nanoseconds since the Unix epoch),
``vehicle`` the 4x4 pose of the vehicle in the world (world <- vehicle), ``mount`` the 4x4 pose of
the sensor's ``to_world`` on the vehicle (vehicle <- sonar, the beam frame at bearing 0) and
``scan`` the `mitsonar.scan.model.Scan` just rendered: one row for a mechanical head's ping, a
whole frame for a multibeam's.
"""
from __future__ import annotations

import sys
import threading
from collections import Counter, deque
from typing import Protocol, runtime_checkable

__all__ = ["LiveOutput", "LiveOutputs", "OutputError"]


class OutputError(ValueError):
    """An output that cannot be opened (a missing package, a port in use, a file that cannot be
    written): one line naming the flag and what is allowed."""


@runtime_checkable
class LiveOutput(Protocol):
    """One destination of the pings (module doc)."""

    def publish(self, t_ns: int, vehicle, mount, scan) -> None:
        """Send one ping; called from `LiveOutputs`' thread, one ping at a time, in order."""

    def close(self) -> None:
        """Finish: close sockets, make files complete and put them in place."""


class LiveOutputs:
    """Fan-out of the pings to ``outputs`` through a bounded queue and one thread.

    `publish` never blocks: when ``maxsize`` pings wait already (the outputs are slower than the
    head), the oldest is dropped and counted in ``stats["dropped"]``. An output that raises is
    counted (``stats["errors"]``), said once on ``out`` and still given the next pings.
    `close` sends what waits, then closes every output; `discard` closes them without waiting,
    and an output with a ``discard`` method (a recording) removes what it wrote.
    """

    def __init__(self, outputs=(), *, maxsize: int = 8, out=None):
        self.outputs = list(outputs)
        self.maxsize = max(1, int(maxsize))
        self.out = sys.stderr if out is None else out
        self.stats: Counter = Counter()
        self._queue: deque = deque()
        self._cond = threading.Condition()
        self._closing = False
        self._said: set = set()
        self._thread = threading.Thread(target=self._run, name="LiveOutputs", daemon=True)
        self._thread.start()

    def __bool__(self) -> bool:
        return bool(self.outputs)

    def publish(self, t_ns: int, vehicle, mount, scan) -> None:
        """Queue one ping for the outputs (module doc); returns at once."""
        with self._cond:
            if self._closing:
                return
            if len(self._queue) >= self.maxsize:
                self._queue.popleft()
                self.stats["dropped"] += 1
            self._queue.append((int(t_ns), vehicle, mount, scan))
            self.stats["queued"] += 1
            self._cond.notify()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._queue and not self._closing:
                    self._cond.wait()
                if not self._queue:
                    return
                ping = self._queue.popleft()
            for output in self.outputs:
                try:
                    output.publish(*ping)
                except Exception as e:        # noqa: BLE001 - an output must not stop the head
                    self.stats["errors"] += 1
                    name = type(output).__name__
                    if name not in self._said:
                        self._said.add(name)
                        print(f"mitsonar live: warning: {name}: {e}", file=self.out, flush=True)
            with self._cond:
                self.stats["published"] += 1
                self._cond.notify_all()

    def flush(self, timeout: float | None = None) -> bool:
        """Wait until every queued ping went out (True) or ``timeout`` seconds passed (False)."""
        with self._cond:
            return self._cond.wait_for(lambda: self.stats["published"] + self.stats["dropped"] >= self.stats["queued"],
                                       timeout)

    def _stop(self) -> None:
        with self._cond:
            self._closing = True
            self._cond.notify_all()
        self._thread.join()

    def close(self) -> None:
        """Send what waits, then close every output (the first error is raised after all closed)."""
        self._stop()
        self._finish("close")

    def discard(self) -> None:
        """Drop what waits and close the outputs, a recording removing its file."""
        with self._cond:
            self.stats["dropped"] += len(self._queue)
            self._queue.clear()
        self._stop()
        self._finish("discard")

    def _finish(self, how: str) -> None:
        first = None
        for output in self.outputs:
            try:
                getattr(output, how, output.close)()
            except Exception as e:            # noqa: BLE001 - close the others, then raise
                first = first or e
        self.outputs = []
        if first is not None:
            raise first

    def summary(self) -> str:
        """``N pings published, D dropped`` (and errors, if any)."""
        st = self.stats
        line = f"{st['published']} pings published, {st['dropped']} dropped"
        return line + (f", {st['errors']} output errors" if st["errors"] else "")
