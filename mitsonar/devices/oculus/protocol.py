"""The Oculus M-series Ethernet protocol: messages, their byte layout, and a stream parser.

Written from the published layout, with the `struct` module (little-endian, packed: the
structures are ``#pragma pack(1)``). The layout is Blueprint's ``Oculus.h`` as the open clients
carry it: liboculus (github.com/apl-ocean-engineering/liboculus, ``thirdparty/Oculus/Oculus.h``,
``include/liboculus/Constants.h``, ``SimplePingResult.h``, ``GainData.h``, ``lib/DataRx.cpp``,
``lib/SonarStatus.cpp``) and oculus-python (PyPI ``oculus-python``, module ``bps_oculus.oculus``:
the same structures as `struct` format strings). Offsets below are bytes from the start of the
message (header included).

``OculusMessageHeader`` (16 bytes, `HEADER`, ``'<5HIH'``)
    0 ``oculusId`` (0x4f53, `OCULUS_ID`), 2 ``srcDeviceId``, 4 ``dstDeviceId``, 6 ``msgId``
    (`MSG`), 8 ``msgVersion``, 10 ``payloadSize`` (u32, the bytes after the header),
    14 ``spare2``.

``OculusSimpleFireMessage`` (msgId 0x15, version 1; 53 bytes) / ``...2`` (version 2; 89 bytes), `FireMessage`
    16 ``masterMode`` (1 low frequency, 2 high frequency), 17 ``pingRate`` (`PING_RATE_HZ`),
    18 ``networkSpeed``, 19 ``gammaCorrection`` (255 or 0 = gamma 1.0, 127 = 0.5),
    20 ``flags`` (`FLAG`), 21 ``range`` (double; ``rangePercent`` in version 2; metres when
    ``flags`` bit 0 is set, else percent of the mode's largest range), 29 ``gainPercent``,
    37 ``speedOfSound`` (m/s; 0: the head computes it from ``salinity``), 45 ``salinity`` (ppt);
    version 2 adds 53 ``extFlags`` (u32; 0x200: 32-bit samples) and 57 ``reserved[8]`` (u32).

``OculusSimplePingResult`` (msgId 0x23, version 1 (or 0); 122 bytes + bearings) / ``...2`` (version 2; 202 bytes + bearings), `PingResult`
    The fire message the ping answers (53 / 89 bytes), then, version 1: 53 ``pingId``,
    57 ``status``, 61 ``frequency`` (Hz), 69 ``temperature``, 77 ``pressure``,
    85 ``speedOfSoundUsed``, 93 ``pingStartTime`` (u32), 97 ``dataSize`` (u8: 0 8-bit,
    1 16-bit, 2 24-bit, 3 32-bit), 98 ``rangeResolution`` (m per range line), 106 ``nRanges``,
    108 ``nBeams`` (u16), 110 ``imageOffset``, 114 ``imageSize``, 118 ``messageSize`` (u32);
    version 2: 89 ``pingId``, 93 ``status``, 97 ``frequency``, 105 ``temperature``,
    113 ``pressure``, 121 ``heading``, 129 ``pitch``, 137 ``roll`` (degrees),
    145 ``speedOfSoundUsed``, 153 ``pingStartTime`` (double, s since power-up), 161 ``dataSize``,
    162 ``rangeResolution``, 170 ``nRanges``, 172 ``nBeams``, 174 ``spare0..3``,
    190 ``imageOffset``, 194 ``imageSize``, 198 ``messageSize``.
    After the structure: ``nBeams`` bearings (int16, 0.01 degree), then at ``imageOffset`` the
    image, ``nRanges`` rows of ``nBeams`` samples (little-endian); with ``flags`` bit 2 (send gain)
    each row starts with 4 bytes of gain (liboculus ``GainData<float>``: a float32).
    ``payloadSize + 16 == imageOffset + imageSize == messageSize`` (bps_oculus checks the first).

``OculusStatusMsg`` (UDP, 142 bytes), `StatusMessage`
    16 ``deviceId`` (u32), 20 ``deviceType`` (u16, 1 imaging sonar), 22 ``partNumber`` (u16,
    `mitsonar.presets.oculus`), 24 ``status`` (u32; bits 0-2 the master state, 3 =
    main run), 28 ``versionInfo`` (6 u32), 52 ``ipAddr``, 56 ``ipMask``, 60 ``connectedIpAddr``
    (u32 in network byte order: liboculus reads them with ``ntohl``), 64 ``macAddr0..5``,
    70 ``temperature0..7`` (double), 134 ``pressure``. liboculus's ``StatusRx`` takes a datagram
    of exactly this size; the header's ``msgId`` is not one of the TCP messages' (this codec
    writes 0x01).

``OculusUserConfigMessage`` (msgId 0x55; 28 bytes), `UserConfig`
    16 ``ipAddr``, 20 ``ipMask``, 24 ``dhcpEnable`` (u32).

Every decoding problem raises `OculusError`, a ValueError naming the field.
"""
from __future__ import annotations

import socket
import struct
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

__all__ = ["OCULUS_ID", "TCP_PORT", "UDP_PORT", "MSG", "FLAG", "EXT_32BIT", "PING_RATE_HZ",
           "DATA_SIZE_BYTES", "OculusError", "Header", "FireMessage", "PingResult", "StatusMessage",
           "UserConfig", "RawMessage", "decode", "StreamParser", "HEADER"]

OCULUS_ID = 0x4F53
#: the head's TCP port (fire messages in, ping results out) and the status broadcast's UDP port
TCP_PORT = 52100
UDP_PORT = 52102

MSG = {"simple_fire": 0x15, "ping_result": 0x22, "simple_ping_result": 0x23, "user_config": 0x55,
       "logs": 0x80, "dummy": 0xFF, "status": 0x01}

#: ``flags`` bits (liboculus ``Constants.h``, ``FlagBits``)
FLAG = {"range_as_meters": 0x01, "data_16bit": 0x02, "send_gain": 0x04, "simple_return": 0x08,
        "gain_assistance": 0x10, "512_beams": 0x40}
#: ``extFlags`` bit of the version 2 fire message for 32-bit samples
EXT_32BIT = 0x200

#: ``pingRate`` code -> ping rate (Hz); 5 is standby (no pings). ``Oculus.h`` ``PingRateType``.
PING_RATE_HZ = {0: 10.0, 1: 15.0, 2: 40.0, 3: 5.0, 4: 2.0, 5: 0.0}
#: ``dataSize`` code -> bytes per sample (``DataSizeType``)
DATA_SIZE_BYTES = {0: 1, 1: 2, 2: 3, 3: 4}
_DTYPE = {1: np.dtype("<u1"), 2: np.dtype("<u2"), 4: np.dtype("<u4")}

HEADER = struct.Struct("<5HIH")                       # 16
_FIRE1 = struct.Struct("<5B4d")                       # 16 + 37 = 53
_FIRE2 = struct.Struct("<5B4d9I")                     # 16 + 73 = 89
_PING1 = struct.Struct("<2I4dIBd2H3I")                # 53 + 69 = 122
_PING2 = struct.Struct("<2I8dBd2H7I")                 # 89 + 113 = 202
_STATUS = struct.Struct("<IHHI6I3I6B9d")              # 16 + 126 = 142
_USER = struct.Struct("<3I")                          # 16 + 12 = 28

FIRE_SIZE = {1: HEADER.size + _FIRE1.size, 2: HEADER.size + _FIRE2.size}
PING_SIZE = {1: FIRE_SIZE[1] + _PING1.size, 2: FIRE_SIZE[2] + _PING2.size}
STATUS_SIZE = HEADER.size + _STATUS.size
USER_CONFIG_SIZE = HEADER.size + _USER.size


class OculusError(ValueError):
    """Bytes that are no valid Oculus message (the text names the field)."""


def _ip_to_u32(ip: str) -> int:
    return int.from_bytes(socket.inet_aton(ip), "little")


def _u32_to_ip(v: int) -> str:
    return socket.inet_ntoa(int(v).to_bytes(4, "little"))


@dataclass
class Header:
    """``OculusMessageHeader``."""
    msg_id: int
    version: int = 1
    payload_size: int = 0
    src: int = 0
    dst: int = 0
    oculus_id: int = OCULUS_ID
    spare: int = 0

    def encode(self) -> bytes:
        return HEADER.pack(self.oculus_id, self.src, self.dst, self.msg_id, self.version,
                           self.payload_size, self.spare)

    @classmethod
    def decode(cls, data: bytes) -> "Header":
        if len(data) < HEADER.size:
            raise OculusError(f"header: {len(data)} bytes, a header is {HEADER.size}")
        oid, src, dst, mid, ver, size, spare = HEADER.unpack_from(data)
        if oid != OCULUS_ID:
            raise OculusError(f"header 'oculusId': 0x{oid:04x} is not 0x{OCULUS_ID:04x}")
        return cls(mid, ver, size, src, dst, oid, spare)


@dataclass
class FireMessage:
    """``OculusSimpleFireMessage`` (``version`` 1) or ``OculusSimpleFireMessage2`` (2)."""
    master_mode: int = 1
    ping_rate: int = 0
    network_speed: int = 0xFF
    gamma: int = 0xFF
    flags: int = FLAG["range_as_meters"] | FLAG["simple_return"]
    range: float = 10.0
    gain: float = 50.0
    speed_of_sound: float = 0.0
    salinity: float = 35.0
    ext_flags: int = 0
    version: int = 2
    src: int = 0
    dst: int = 0
    reserved: tuple = (0,) * 8

    @property
    def n_beams(self) -> int:
        """512 with ``flags`` bit 6, else 256."""
        return 512 if self.flags & FLAG["512_beams"] else 256

    @property
    def data_bytes(self) -> int:
        """Bytes per sample asked for: 4 (version 2 ``extFlags`` 0x200), 2 (``flags`` bit 1) or 1."""
        if self.version == 2 and self.ext_flags & EXT_32BIT:
            return 4
        return 2 if self.flags & FLAG["data_16bit"] else 1

    @property
    def send_gain(self) -> bool:
        return bool(self.flags & FLAG["send_gain"])

    def _body(self) -> bytes:
        common = (self.master_mode, self.ping_rate, self.network_speed, self.gamma, self.flags,
                  self.range, self.gain, self.speed_of_sound, self.salinity)
        if self.version == 2:
            return _FIRE2.pack(*common, self.ext_flags, *self.reserved)
        return _FIRE1.pack(*common)

    def encode(self) -> bytes:
        if self.version not in (1, 2):
            raise OculusError(f"fire message 'msgVersion': {self.version} is not allowed (1 or 2)")
        body = self._body()
        return Header(MSG["simple_fire"], self.version, len(body), self.src, self.dst).encode() + body

    @classmethod
    def decode(cls, data: bytes, header: Header | None = None) -> "FireMessage":
        h = Header.decode(data) if header is None else header
        version = 2 if h.version == 2 else 1
        need = FIRE_SIZE[version]
        if len(data) < need:
            raise OculusError(f"simple fire message v{version}: {len(data)} bytes, it needs {need}")
        st = _FIRE2 if version == 2 else _FIRE1
        v = st.unpack_from(data, HEADER.size)
        m = cls(*v[:9], version=version, src=h.src, dst=h.dst)
        if version == 2:
            m.ext_flags, m.reserved = v[9], tuple(v[10:])
        return m


@dataclass
class PingResult:
    """``OculusSimplePingResult`` (``version`` 1) or ``...2`` (2), with its bearings, image and gains.

    ``image``: (n_ranges, n_beams) uint8 / uint16 / uint32 (24-bit samples decode as uint32);
    ``bearings``: int16 (n_beams,), 0.01 degree; ``gains``: float32 (n_ranges,) or None.
    """
    fire: FireMessage
    image: np.ndarray
    bearings: np.ndarray
    range_resolution: float
    gains: np.ndarray | None = None
    ping_id: int = 0
    status: int = 0
    frequency: float = 0.0
    temperature: float = 0.0
    pressure: float = 0.0
    heading: float = 0.0
    pitch: float = 0.0
    roll: float = 0.0
    speed_of_sound_used: float = 0.0
    ping_start_time: float = 0.0
    data_size: int | None = None       # None: from image's dtype
    src: int = 0
    dst: int = 0

    @property
    def version(self) -> int:
        return self.fire.version

    @property
    def n_ranges(self) -> int:
        return int(self.image.shape[0])

    @property
    def n_beams(self) -> int:
        return int(self.image.shape[1])

    @property
    def bearings_deg(self) -> np.ndarray:
        return np.asarray(self.bearings, np.float64) / 100.0

    def encode(self) -> bytes:
        img = np.asarray(self.image)
        if img.ndim != 2 or img.dtype.itemsize not in (1, 2, 4) or img.dtype.kind != "u":
            raise OculusError(f"ping result 'image': {img.dtype} {img.shape} is not a 2-D uint8/16/32 array")
        n_ranges, n_beams = img.shape
        if not (0 < n_ranges < 65536 and 0 < n_beams < 65536):
            raise OculusError(f"ping result 'nRanges'/'nBeams': {n_ranges} x {n_beams} is not allowed (1..65535)")
        bearings = np.asarray(self.bearings)
        if bearings.shape != (n_beams,):
            raise OculusError(f"ping result 'bearings': {bearings.shape[0] if bearings.ndim else 0} "
                              f"for {n_beams} beams")
        nb = img.dtype.itemsize
        dsize = {1: 0, 2: 1, 4: 3}[nb] if self.data_size is None else self.data_size
        rows = img.astype(_DTYPE[nb], copy=False)
        if self.fire.send_gain:
            g = np.zeros(n_ranges, np.float32) if self.gains is None else np.asarray(self.gains, "<f4")
            if g.shape != (n_ranges,):
                raise OculusError(f"ping result 'gains': {g.shape} for {n_ranges} range lines")
            image = np.concatenate([g.view(np.uint8).reshape(n_ranges, 4),
                                    rows.view(np.uint8).reshape(n_ranges, n_beams * nb)], axis=1).tobytes()
        else:
            image = rows.tobytes()
        head_size = PING_SIZE[self.version]
        offset = head_size + 2 * n_beams
        total = offset + len(image)
        fire_bytes = self.fire._body()
        header = Header(MSG["simple_ping_result"], self.version, total - HEADER.size, self.src, self.dst)
        if self.version == 2:
            tail = _PING2.pack(self.ping_id, self.status, self.frequency, self.temperature, self.pressure,
                               self.heading, self.pitch, self.roll, self.speed_of_sound_used,
                               float(self.ping_start_time), dsize, self.range_resolution, n_ranges, n_beams,
                               0, 0, 0, 0, offset, len(image), total)
        else:
            tail = _PING1.pack(self.ping_id, self.status, self.frequency, self.temperature, self.pressure,
                               self.speed_of_sound_used, int(self.ping_start_time) & 0xFFFFFFFF, dsize,
                               self.range_resolution, n_ranges, n_beams, offset, len(image), total)
        return (header.encode() + fire_bytes + tail + bearings.astype("<i2").tobytes() + image)

    @classmethod
    def decode(cls, data: bytes, header: Header | None = None) -> "PingResult":
        h = Header.decode(data) if header is None else header
        version = 2 if h.version == 2 else 1
        if h.version not in (0, 1, 2):
            raise OculusError(f"simple ping result 'msgVersion': {h.version} is not allowed (0, 1 or 2)")
        size = PING_SIZE[version]
        if len(data) < size:
            raise OculusError(f"simple ping result v{version}: {len(data)} bytes, it needs {size}")
        fire = FireMessage.decode(data, Header(MSG["simple_fire"], version, 0, h.src, h.dst))
        if version == 2:
            (pid, status, freq, temp, pres, heading, pitch, roll, c, t0, dsize, res, n_r, n_b,
             _s0, _s1, _s2, _s3, off, isize, msize) = _PING2.unpack_from(data, FIRE_SIZE[2])
        else:
            (pid, status, freq, temp, pres, c, t0, dsize, res, n_r, n_b, off, isize,
             msize) = _PING1.unpack_from(data, FIRE_SIZE[1])
            heading = pitch = roll = 0.0
        if dsize not in DATA_SIZE_BYTES:
            raise OculusError(f"simple ping result 'dataSize': {dsize} is not allowed (0..3)")
        nb = DATA_SIZE_BYTES[dsize]
        if n_r == 0 or n_b == 0:
            raise OculusError(f"simple ping result 'nRanges'/'nBeams': {n_r} x {n_b} (an empty image)")
        if off < size + 2 * n_b:
            raise OculusError(f"simple ping result 'imageOffset': {off} is inside the header and "
                              f"bearings ({size + 2 * n_b} bytes)")
        gain = bool(fire.flags & FLAG["send_gain"])
        stride = n_b * nb + (4 if gain else 0)
        if isize != stride * n_r:
            raise OculusError(f"simple ping result 'imageSize': {isize} is not {n_r} range lines of "
                              f"{stride} bytes")
        if off + isize > len(data):
            raise OculusError(f"simple ping result: the image ends at byte {off + isize}, "
                              f"the message has {len(data)}")
        bearings = np.frombuffer(data, "<i2", n_b, size).astype(np.int16)
        raw = np.frombuffer(data, np.uint8, isize, off).reshape(n_r, stride)
        gains = None
        if gain:
            gains = raw[:, :4].copy().view("<f4").reshape(n_r).astype(np.float32)
            raw = raw[:, 4:]
        raw = np.ascontiguousarray(raw)
        if nb == 3:     # 24-bit samples: widen to uint32
            b = raw.reshape(n_r, n_b, 3).astype(np.uint32)
            image = b[..., 0] | (b[..., 1] << 8) | (b[..., 2] << 16)
        else:
            image = raw.view(_DTYPE[nb]).reshape(n_r, n_b).astype(_DTYPE[nb].newbyteorder("="))
        return cls(fire=fire, image=image, bearings=bearings, range_resolution=res, gains=gains,
                   ping_id=pid, status=status, frequency=freq, temperature=temp, pressure=pres,
                   heading=heading, pitch=pitch, roll=roll, speed_of_sound_used=c, ping_start_time=t0,
                   data_size=dsize, src=h.src, dst=h.dst)


@dataclass
class StatusMessage:
    """``OculusStatusMsg``: what a head broadcasts on UDP `UDP_PORT` about once a second."""
    device_id: int = 1
    part_number: int = 0
    ip: str = "127.0.0.1"
    mask: str = "255.0.0.0"
    connected_ip: str = "0.0.0.0"
    status: int = 3               # oculusMasterStatusMainRun
    device_type: int = 1          # deviceTypeImagingSonar
    versions: tuple = (0,) * 6
    mac: tuple = (0x02, 0, 0, 0, 0, 1)
    temperatures: tuple = (0.0,) * 8
    pressure: float = 0.0
    src: int = 0
    dst: int = 0

    def encode(self) -> bytes:
        body = _STATUS.pack(self.device_id, self.device_type, self.part_number, self.status, *self.versions,
                            _ip_to_u32(self.ip), _ip_to_u32(self.mask), _ip_to_u32(self.connected_ip),
                            *self.mac, *self.temperatures, self.pressure)
        return Header(MSG["status"], 1, len(body), self.src, self.dst).encode() + body

    @classmethod
    def decode(cls, data: bytes, header: Header | None = None) -> "StatusMessage":
        h = Header.decode(data) if header is None else header
        if len(data) < STATUS_SIZE:
            raise OculusError(f"status message: {len(data)} bytes, it needs {STATUS_SIZE}")
        v = _STATUS.unpack_from(data, HEADER.size)
        return cls(device_id=v[0], device_type=v[1], part_number=v[2], status=v[3], versions=tuple(v[4:10]),
                   ip=_u32_to_ip(v[10]), mask=_u32_to_ip(v[11]), connected_ip=_u32_to_ip(v[12]),
                   mac=tuple(v[13:19]), temperatures=tuple(v[19:27]), pressure=v[27], src=h.src, dst=h.dst)


@dataclass
class UserConfig:
    """``OculusUserConfigMessage``: the head's address settings."""
    ip: str = "0.0.0.0"
    mask: str = "255.255.255.0"
    dhcp: int = 0
    src: int = 0
    dst: int = 0

    def encode(self) -> bytes:
        body = _USER.pack(_ip_to_u32(self.ip), _ip_to_u32(self.mask), self.dhcp)
        return Header(MSG["user_config"], 1, len(body), self.src, self.dst).encode() + body

    @classmethod
    def decode(cls, data: bytes, header: Header | None = None) -> "UserConfig":
        h = Header.decode(data) if header is None else header
        if len(data) < USER_CONFIG_SIZE:
            raise OculusError(f"user config message: {len(data)} bytes, it needs {USER_CONFIG_SIZE}")
        ip, mask, dhcp = _USER.unpack_from(data, HEADER.size)
        return cls(_u32_to_ip(ip), _u32_to_ip(mask), dhcp, h.src, h.dst)


@dataclass
class RawMessage:
    """A well-framed message of a type this codec does not decode (full ping results, logs, ...)."""
    header: Header
    payload: bytes = field(repr=False, default=b"")


_DECODERS = {MSG["simple_fire"]: FireMessage, MSG["simple_ping_result"]: PingResult,
             MSG["user_config"]: UserConfig}


def decode(data: bytes):
    """One whole message (header and payload) as its class; `RawMessage` for other types."""
    h = Header.decode(data)
    if len(data) != HEADER.size + h.payload_size:
        raise OculusError(f"header 'payloadSize': {h.payload_size} but {len(data) - HEADER.size} "
                          f"bytes follow the header")
    cls = _DECODERS.get(h.msg_id)
    if cls is None:
        return RawMessage(h, bytes(data[HEADER.size:]))
    return cls.decode(data, h)


class StreamParser:
    """Cut a TCP byte stream into messages: ``feed(bytes) -> [message]``.

    A message starts with the id bytes ``53 4f``; bytes before one are dropped. A header whose
    ``payloadSize`` exceeds ``max_payload`` (default 16 MiB) is refused: its id bytes are
    dropped and the search goes on after them. A whole message that does not decode is dropped
    whole. ``packets`` counts the messages returned, ``dropped`` the bytes dropped,
    ``drop_reasons`` why (`collections.Counter`), ``refused`` the messages refused (oversized
    or malformed), ``last_problem`` the last reason, one line; ``refusals`` lists the last
    feed's refusals in order, as ``(k, reason)``: after its k-th message returned.
    """

    def __init__(self, max_payload: int = 16 << 20):
        self.max_payload = int(max_payload)
        self._buf = bytearray()
        self.packets = 0
        self.dropped = 0
        self.refused = 0
        self.drop_reasons: Counter = Counter()
        self.last_problem: str | None = None
        self.raw: list = []       # the bytes of each message returned by the last feed
        self.refusals: list = []

    def _drop(self, n: int, reason: str, refused: bool = False) -> None:
        del self._buf[:n]
        self.dropped += n
        self.drop_reasons[reason] += n
        if refused:
            self.refused += 1
            self.last_problem = reason
            self.refusals.append((len(self.raw), reason))

    def feed(self, data: bytes) -> list:
        self._buf += data
        out = []
        self.raw = []
        self.refusals = []
        while True:
            i = self._buf.find(b"\x53\x4f")
            if i < 0:
                keep = 1 if self._buf[-1:] == b"\x53" else 0
                if len(self._buf) > keep:
                    self._drop(len(self._buf) - keep, "bytes before a message id")
                return out
            if i > 0:
                self._drop(i, "bytes before a message id")
            if len(self._buf) < HEADER.size:
                return out
            h = Header.decode(bytes(self._buf[:HEADER.size]))
            if h.payload_size > self.max_payload:
                self._drop(2, f"message 0x{h.msg_id:02x}: payloadSize {h.payload_size} is over the "
                              f"limit of {self.max_payload} bytes", refused=True)
                continue
            n = HEADER.size + h.payload_size
            if len(self._buf) < n:
                return out
            raw = bytes(self._buf[:n])
            try:
                m = decode(raw)
            except OculusError as e:
                self._drop(n, f"message 0x{h.msg_id:02x}: {e}", refused=True)
                continue
            del self._buf[:n]
            self.packets += 1
            out.append(m)
            self.raw.append(raw)

    def flush(self) -> list:
        """Drop what is buffered (an incomplete message at the end of a stream); returns []
        (no whole message is left)."""
        if self._buf:
            self._drop(len(self._buf), "an incomplete message at the end")
        return []

    @property
    def pending(self) -> int:
        return len(self._buf)
