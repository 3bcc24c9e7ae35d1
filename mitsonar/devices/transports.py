"""Byte transports of the serial devices: the driver's side of a port and the virtual head's.

The driver (`mitsonar.devices.micron.driver.MicronSonar`) and the passive recorder open a port with
`open_serial` (``serial.serial_for_url``: a device path, ``socket://host:port``, ``rfc2217://``,
``loop://`` ...) and read it with `read_available`. The virtual head (`mitsonar.devices.micron.virtual`)
serves on `open_transport`: a new pseudo-terminal, a TCP port that pyserial ``socket://``
clients connect to, a UDP port (``udp://127.0.0.1:PORT``, loopback only: a virtual Ping360
answers the sender of the last datagram, as the real head does on its Ethernet port), or any
pyserial URL. The host's side opens ``udp://HOST:PORT`` with `open_serial` as well.

What both heads share is here too: `LineDriver`, the base of both drivers (port, raw log, pose,
polling, scans from an assembler), and `ServedHead`, the base of both virtual heads (port,
thread, foreground serving). Nothing here knows SeaNet or ping-protocol.
"""
from __future__ import annotations

import os
import select
import socket
import sys
import threading
import time
from urllib.parse import urlparse

__all__ = ["SonarError", "SonarTimeout", "open_serial", "serial_fileno", "read_available",
           "open_transport", "check_port", "UdpPort", "LineDriver", "ServedHead"]


class SonarError(RuntimeError):
    """The head or the port misbehaved beyond what the driver can recover from."""


class SonarTimeout(SonarError, TimeoutError):
    """The head did not answer in time."""


# --------------------------------------------------------------------------------------------
# The host's side: pyserial
# --------------------------------------------------------------------------------------------

class UdpPort:
    """The host's side of a UDP head (``udp://HOST:PORT``): a connected datagram socket with the
    ``write``/``close`` of a pyserial port; `read_available` reads it through ``_socket``."""

    def __init__(self, host: str, port: int):
        self.port = f"udp://{host}:{port}"
        self._socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self._socket.connect((host, port))
        except BaseException:
            self._socket.close()
            raise
        self._socket.setblocking(False)

    def write(self, data: bytes) -> int:
        return self._socket.send(bytes(data))

    def reset_input_buffer(self) -> None:
        while True:
            try:
                self._socket.recv(65536)
            except OSError:
                return

    def close(self) -> None:
        self._socket.close()


def _host_port(url: str, scheme: str) -> tuple[str, int]:
    u = urlparse(url)
    if u.port is None or not u.hostname:
        raise ValueError(f"needs a host and a port ({scheme}://HOST:PORT)")
    return u.hostname, u.port


def open_serial(port_or_url, baudrate: int, timeout: float, write_timeout: float | None = None):
    """``serial.serial_for_url`` of ``port_or_url`` (`UdpPort` for ``udp://HOST:PORT``);
    `SonarError` "cannot open PORT: reason"."""
    import serial
    if isinstance(port_or_url, str) and port_or_url.startswith("udp://"):
        try:
            return UdpPort(*_host_port(port_or_url, "udp"))
        except (OSError, ValueError) as e:
            raise SonarError(f"cannot open {port_or_url}: {e}") from None
    try:
        return serial.serial_for_url(os.fspath(port_or_url), baudrate=baudrate, timeout=timeout,
                                     write_timeout=write_timeout)
    except (serial.SerialException, OSError, ValueError) as e:
        raise SonarError(f"cannot open {port_or_url}: {e}") from None


def serial_fileno(ser):
    """A file descriptor ``select`` can wait on, or None (sockets, ``loop://``, ``rfc2217://``)."""
    if getattr(ser, "_socket", None) is not None:
        return None
    try:
        fd = ser.fileno()
        select.select([fd], [], [], 0)
        return fd
    except Exception:        # loop://, rfc2217:// and friends have no file descriptor
        return None


def read_available(ser, fd, wait: float, port) -> bytes:
    """What ``ser`` has within ``wait`` seconds (b"" if nothing); `SonarError` naming ``port``.

    ``fd`` is `serial_fileno` (ser). Waits in ``select`` where it can, so the port's own timeout
    is left alone (setting it costs a tcsetattr on every poll).
    """
    wait = max(0.0, wait)
    try:
        sock = getattr(ser, "_socket", None)
        if sock is not None:
            # pyserial's socket:// reports in_waiting as 0 or 1, which would mean one
            # read call per byte: wait on the socket and take all it has.
            r, _, _ = select.select([sock], [], [], wait)
            data = sock.recv(65536) if r else b""
            if r and not data:
                raise SonarError(f"{port}: connection closed by the other end")
        elif fd is not None:
            r, _, _ = select.select([fd], [], [], wait)
            data = ser.read(max(1, ser.in_waiting)) if r else b""
        else:
            if ser.timeout != wait:
                ser.timeout = wait
            n = ser.in_waiting
            data = ser.read(n if n > 0 else 1)
    except SonarError:
        raise
    except Exception as e:
        raise SonarError(f"{port}: read failed: {e}") from None
    return data


class LineDriver:
    """What every head driver does with its line (`mitsonar.devices.micron.driver.MicronSonar`,
    `mitsonar.devices.ping360.driver.Ping360Sonar`): open it, send and receive bytes through the raw log
    (``_log``, a `mitsonar.devices.rawlog.RawLogWriter` or None), count what was sent (``stats``), hold
    the head's mounting (``pose``, checked by the subclass's ``_check_pose``), close.

    Subclasses call `_init_line`, set ``stats``, ``parser`` and ``_inbox`` (a deque), then call
    `_attach`; they define ``start``,
    ``read_ping``, ``_log_meta`` and ``_expected_step_time`` (s per ping when all goes well).
    """

    _ser = None
    _fd = None
    _log = None
    _own_log = False

    def _init_line(self, settings, baudrate: int, pose, timeout, ping_timeout, retries, **more_timeouts) -> None:
        """Check and keep what every driver takes: settings, baud rate, mounting pose, timeouts
        (``more_timeouts``, e.g. ``boot_timeout``, are only checked) and retries."""
        self._check_timing(timeout, ping_timeout, retries, **more_timeouts)
        self._settings = settings
        self.baudrate = int(baudrate)
        self._pose = self._check_pose(pose)
        self.timeout = float(timeout)
        self._ping_timeout = ping_timeout
        self.retries = retries

    @staticmethod
    def _check_timing(timeout, ping_timeout, retries, **more_timeouts) -> None:
        """Refuse a timeout that is not a positive number of seconds, retries below 0."""
        for name, v in (("timeout", timeout), *more_timeouts.items()):
            if not (isinstance(v, (int, float)) and v > 0):
                raise ValueError(f"{name} must be a positive number of seconds, got {v!r}")
        if ping_timeout is not None and not (isinstance(ping_timeout, (int, float)) and ping_timeout > 0):
            raise ValueError(f"ping_timeout must be a positive number of seconds, got {ping_timeout!r}")
        if not (isinstance(retries, int) and retries >= 0):
            raise ValueError(f"retries must be an integer >= 0, got {retries!r}")

    def _attach(self, port_or_url, log, start) -> None:
        """Name the port, open the log (a path, or a `RawLogWriter` to share), open the line
        (`open_serial`, unless ``port_or_url`` is an open pyserial-like object) and call
        ``start()`` if given; on any failure close what was opened."""
        from mitsonar.devices.rawlog import RawLogWriter
        self.port = (port_or_url if isinstance(port_or_url, str)
                     else getattr(port_or_url, "port", repr(port_or_url)))
        if log is not None:
            if isinstance(log, RawLogWriter):
                self._log = log
            else:
                self._log = RawLogWriter(log, self._log_meta())
                self._own_log = True
        try:
            if isinstance(port_or_url, (str, os.PathLike)):
                self._ser = open_serial(os.fspath(port_or_url), self.baudrate, timeout=0.05,
                                        write_timeout=max(1.0, self.timeout))
            else:
                self._ser = port_or_url
            self._fd = serial_fileno(self._ser)
            if start is not None:
                start()
        except BaseException:
            self.close()
            raise

    @property
    def settings(self):
        return self._settings

    @property
    def ping_timeout(self) -> float:
        """s to wait for one reply: as given, else 2x the expected step time + 0.5 s."""
        if self._ping_timeout is not None:
            return float(self._ping_timeout)
        return 2.0 * self._expected_step_time() + 0.5

    def scan(self):
        """The next whole scan of the head's assembler (``_scan_assembler()``), as a `Scan` whose
        ``meta`` names the port, the settings and what the head said of itself (``_head_meta``)."""
        asm = self._scan_assembler()
        while True:
            ping = self.read_ping()
            scan = asm.add(ping, self._pose, self.last_ping_time)
            if scan is not None:
                scan.meta = scan.meta.replace(port=str(self.port), settings=self._settings.as_dict(),
                                              **self._head_meta())
                return scan

    def pings(self, count: int | None = None):
        """Iterator over the head's pings (``read_ping``), forever or ``count`` of them."""
        k = 0
        while count is None or k < count:
            yield self.read_ping()
            k += 1

    @staticmethod
    def _check_pose(T):
        raise NotImplementedError

    @property
    def pose(self):
        return self._pose

    @pose.setter
    def pose(self, T) -> None:
        self._pose = self._check_pose(T)
        if self._log is not None:
            self._log.pose(self._pose)

    def _send_bytes(self, data: bytes, name: str) -> None:
        if self._ser is None:
            raise SonarError("the sonar is closed")
        try:
            self._ser.write(data)
        except Exception as e:
            raise SonarError(f"{self.port}: write failed: {e}") from None
        if self._log is not None:
            self._log.tx(data)
        self.stats[f"sent {name}"] += 1

    def _read_some(self, wait: float) -> bytes:
        if self._ser is None:
            raise SonarError("the sonar is closed")
        data = read_available(self._ser, self._fd, wait, self.port)
        if data and self._log is not None:
            self._log.rx(data)
        return data

    def _poll(self, deadline: float):
        """Next message (``parser.feed`` of what arrives, queued in ``_inbox``), or None once
        ``deadline`` (monotonic) passes. ``_seen`` sees every message as it arrives."""
        while True:
            if self._inbox:
                return self._inbox.popleft()
            now = time.monotonic()
            if now >= deadline:
                return None
            data = self._read_some(min(deadline - now, 0.1))
            if data:
                msgs = self.parser.feed(data)
                self._seen(msgs)
                self._inbox.extend(msgs)

    def _seen(self, msgs: list) -> None:
        pass

    def close(self) -> None:
        """Close the port (and the log if the driver opened it). Safe to call twice."""
        ser, self._ser = self._ser, None
        if ser is not None:
            try:
                ser.close()
            except Exception:      # closing a vanished device must not mask the real error
                pass
        if self._own_log and self._log is not None:
            self._log.close()
        self._log = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass


# --------------------------------------------------------------------------------------------
# The virtual head's side
# --------------------------------------------------------------------------------------------

class ServedHead:
    """What every virtual head does with its port (`mitsonar.devices.micron.virtual.VirtualMicron`,
    `mitsonar.devices.ping360.virtual.VirtualPing360`): open it (`open_transport` of ``port_url``) and
    run its ``_tick`` in a thread until `stop`. Subclasses set ``port_url``, ``baudrate``, ``_stop``
    (a `threading.Event`), ``_thread = None``, ``_transport = None``, and may prepare the head
    in ``_power_on`` (called with the port open, before the thread starts)."""

    def _power_on(self) -> None:
        pass

    def _run(self) -> None:
        """Call ``_tick`` (one round: due output, input, commands) until `stop`; an exception in
        it is kept in ``last_error`` and counted (``stats["internal errors"]``), and the head
        goes on."""
        while not self._stop.is_set():
            try:
                self._tick()
            except Exception as e:      # keep the head alive; the test or user sees last_error
                self.last_error = e
                self.stats["internal errors"] += 1
                time.sleep(0.01)

    @property
    def port(self) -> str | None:
        return None if self._transport is None else self._transport.port

    def summary(self) -> str:
        """What the head served, for ``mitsonar live``'s summary line: nothing more here (a serial
        head answers each request as it comes; `mitsonar.devices.oculus.virtual.VirtualOculus`
        says its pings and the ping slots it skipped)."""
        return ""

    def start(self) -> str:
        """Open the port, power the head on; returns the port a driver should open."""
        if self._thread is None:
            self._transport = open_transport(self.port_url, self.baudrate)
            self._stop.clear()
            self._power_on()
            self._thread = threading.Thread(target=self._run, name=type(self).__name__, daemon=True)
            self._thread.start()
        return self.port

    def stop(self, timeout: float = 5.0) -> None:
        """Stop the head and close the port (safe to call twice)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout)
            self._thread = None
        if self._transport is not None:
            self._transport.close()
            self._transport = None

    def close(self) -> None:
        self.stop()

    def __enter__(self):
        self.start()
        return self

    def __exit__(self, *exc):
        self.stop()

    def serve(self, seconds: float | None = None, out=None, label: str = "virtual head") -> int:
        """Run in the foreground: print ``LABEL on PORT``, serve until ``seconds``, Ctrl-C (SIGINT)
        or SIGTERM, then close the port and return 0 (`serve_in_foreground`)."""
        serve_in_foreground(self, seconds, lambda: f"{label} on {self.port}", out)
        return 0


def serve_in_foreground(head, seconds: float | None, banner, out=None) -> None:
    """Serve ``head`` (a context manager that opens its ports on entry and closes them on exit):
    print ``banner()`` (called once the ports are open: a port 0 has its number then), then wait until ``seconds`` have passed, Ctrl-C (SIGINT) or SIGTERM.

    From the main thread the two signals are caught for the time of serving (the handlers
    before are put back): a head started in the background by a shell, which starts it with
    SIGINT ignored (and Python then installs no KeyboardInterrupt), or stopped by a service
    manager's SIGTERM, still closes its port and ends cleanly."""
    import signal

    out = sys.stdout if out is None else out
    stop = threading.Event()
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            previous[sig] = signal.signal(sig, lambda *_: stop.set())
    try:
        with head:
            print(banner(), file=out, flush=True)
            end = None if seconds is None else time.monotonic() + seconds
            try:
                while not stop.is_set() and (end is None or time.monotonic() < end):
                    stop.wait(0.05 if end is None else max(0.0, min(0.05, end - time.monotonic())))
            except KeyboardInterrupt:  # serving from another thread: Python's own handler
                pass
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


class _PtyTransport:
    def __init__(self):
        self.master, self.slave = os.openpty()
        # Raw mode before anyone opens the slave: no echo, no CR/LF translation of binary data.
        import tty  # POSIX only: the offline tools (replay, map) import this module too

        tty.setraw(self.slave)
        tty.setraw(self.master)
        os.set_blocking(self.master, False)
        self.port = os.ttyname(self.slave)

    def read(self, timeout: float) -> bytes:
        r, _, _ = select.select([self.master], [], [], max(0.0, timeout))
        if not r:
            return b""
        try:
            return os.read(self.master, 65536)
        except (BlockingIOError, InterruptedError):
            return b""
        except OSError:          # EIO: nobody holds the slave open (we do, so rarely)
            time.sleep(min(timeout, 0.01))
            return b""

    def write(self, data: bytes) -> int:
        try:
            return os.write(self.master, data)
        except (BlockingIOError, InterruptedError):
            return 0

    def close(self) -> None:
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


class _TcpServerTransport:
    """Listens on host:port; one client at a time (``socket://host:port`` in pyserial)."""

    def __init__(self, host: str, port: int):
        self.server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            self.server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.server.bind((host, port))
            self.server.listen(1)
        except BaseException:
            self.server.close()
            raise
        self.server.setblocking(False)
        h, p = self.server.getsockname()[:2]
        self.port = f"socket://{host or h}:{p}"
        self.client = None

    def read(self, timeout: float) -> bytes:
        socks = [self.server] + ([self.client] if self.client else [])
        r, _, _ = select.select(socks, [], [], max(0.0, timeout))
        if self.server in r:
            try:
                c, _ = self.server.accept()
                c.setblocking(False)
                c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                if self.client is not None:
                    self.client.close()
                self.client = c
            except OSError:
                pass
        if self.client is not None and self.client in r:
            try:
                data = self.client.recv(65536)
            except (BlockingIOError, InterruptedError):
                return b""
            except OSError:
                data = b""
            if not data:
                self.client.close()
                self.client = None
            return data
        return b""

    def write(self, data: bytes) -> int:
        if self.client is None:
            return len(data)      # nobody on the line: the bytes are lost, as on a wire
        try:
            return self.client.send(data)
        except (BlockingIOError, InterruptedError):
            return 0
        except OSError:
            self.client.close()
            self.client = None
            return len(data)

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
        self.server.close()


class _UdpServerTransport:
    """Bound to 127.0.0.1:port; answers the sender of the last datagram (``udp://`` clients)."""

    def __init__(self, host: str, port: int):
        if host not in ("127.0.0.1", "localhost"):
            raise ValueError(f"serves on the loopback only (udp://127.0.0.1:PORT), not {host}")
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.sock.bind(("127.0.0.1", port))
        except BaseException:
            self.sock.close()
            raise
        self.sock.setblocking(False)
        self.port = f"udp://127.0.0.1:{self.sock.getsockname()[1]}"
        self.peer = None

    def read(self, timeout: float) -> bytes:
        r, _, _ = select.select([self.sock], [], [], max(0.0, timeout))
        if not r:
            return b""
        try:
            data, self.peer = self.sock.recvfrom(65536)
        except OSError:          # ICMP unreachable of an earlier send, or nothing after all
            return b""
        return data

    def write(self, data: bytes) -> int:
        if self.peer is None:
            return len(data)      # nobody asked yet: the datagram is lost
        try:
            self.sock.sendto(data, self.peer)
        except (BlockingIOError, InterruptedError):
            return 0
        except OSError:
            pass
        return len(data)

    def close(self) -> None:
        self.sock.close()


class _SerialTransport:
    def __init__(self, url: str, baudrate: int):
        import serial
        self.ser = serial.serial_for_url(url, baudrate=baudrate, timeout=0, write_timeout=0)
        self.port = url
        try:
            self.fd = self.ser.fileno()
        except Exception:       # URL handlers without a descriptor: poll instead
            self.fd = None

    def read(self, timeout: float) -> bytes:
        if self.fd is not None:
            r, _, _ = select.select([self.fd], [], [], max(0.0, timeout))
            return self.ser.read(max(1, self.ser.in_waiting)) if r else b""
        n = self.ser.in_waiting
        if n:
            return self.ser.read(n)
        time.sleep(min(max(0.0, timeout), 0.005))
        return b""

    def write(self, data: bytes) -> int:
        try:
            return self.ser.write(data) or 0
        except Exception:      # write timeout: line busy, try again later
            return 0

    def close(self) -> None:
        self.ser.close()


def open_transport(port_url: str | None, baudrate: int):
    if port_url is None or port_url in ("pty", "pty://"):
        return _PtyTransport()
    # The reason alone ("Name or service not known") does not say which port failed.
    try:
        if port_url.startswith("socket://"):
            u = urlparse(port_url)
            if u.port is None:
                raise ValueError("needs a port (socket://HOST:PORT, 0 for any)")
            return _TcpServerTransport(u.hostname or "localhost", u.port)
        if port_url.startswith("udp://"):
            return _UdpServerTransport(*_host_port(port_url, "udp"))
        return _SerialTransport(port_url, baudrate)
    except OSError as e:     # also serial.SerialException and socket.gaierror
        # pyserial wraps the OS's reason in its own sentence, which names the port again.
        inner = e.__context__ if isinstance(e.__context__, OSError) and e.__context__.strerror else e
        raise OSError(f"cannot open port {port_url}: {inner.strerror or inner}") from None
    except ValueError as e:  # URL syntax: unknown scheme, port out of range, no port
        raise ValueError(f"cannot open port {port_url}: {e}") from None


def check_port(port_url: str | None, baudrate: int = 115200) -> None:
    """Open and close the port `serve` would use, so that a bad URL fails before a long render.

    Raises OSError or ValueError naming the port. A new pseudo-terminal (None) needs no check.
    """
    if port_url is None or port_url in ("pty", "pty://"):
        return
    open_transport(port_url, baudrate).close()
