"""Side-scan scans as an XTF file (eXtended Triton Format, the structures of Triton's XTF format
document rev 35 and later: ``XTFFILEHEADER``, ``CHANINFO``, ``XTFPINGHEADER``, ``XTFPINGCHANHEADER``),
the file side-scan software (SonarWiz, SeaView, PINGMapper, OpenSidescan) opens.

    from mitsonar.export.xtf import write_xtf
    write_xtf("survey.xtf", scans, frame, start=1.7e9)     # frame: a mitsonar.geometry.geodesy.GeoFrame

The file: one 1024-byte ``XTFFILEHEADER`` (two sonar channels: ``CHANINFO`` 0 ``TypeOfChannel`` 1
port, 1 ``TypeOfChannel`` 2 starboard, 1 byte a sample, ``SampleFormat`` 8 (a 16- or 32-bit A/D's
uint16, uint32 ``data``: 2 or 4 bytes, ``SampleFormat`` 3 or 2; one type in a file), slant range; ``NavUnits``
3: navigation in lat/lon), then one sonar packet (``HeaderType`` 0) per ping: its 256-byte
``XTFPINGHEADER`` and, per channel, a 64-byte ``XTFPINGCHANHEADER`` followed by the samples,
the record padded with zeros to a multiple of 64 bytes (``NumBytesThisRecord`` holds the padded
length). Ping k of a scan pairs the port row k with the starboard row k; the samples are the
scan's ``data`` rows, sample for sample (little-endian).

Navigation: ``SensorXcoordinate`` longitude and ``SensorYcoordinate`` latitude (WGS 84 degrees) of
the transducer of that ping (``poses[k][:3, 3]`` of its port row, converted through the frame's CRS),
``ShipXcoordinate``/``ShipYcoordinate`` the vehicle's (the trajectory's position when one is
given, else the transducer's); ``SensorHeading`` the head's forward axis as an azimuth from true
north (meridian convergence included), ``ShipGyro`` the vehicle's; ``SensorSpeed``/``ShipSpeed``
in knots (the track's speed); ``SensorDepth`` m below z = 0; ``SensorPrimaryAltitude`` the first
bottom return (m; 0 where none); ``SoundVelocity`` the one-way speed of sound (m/s). Times: the
ping's time (``--start`` + the scan's ``start_time`` + its row time, seconds of the Unix epoch, UTC)
in ``Year`` .. ``HSeconds`` and ``JulianDay``, rounded to the hundredth of a second the sonar
packet holds; ``NavFixMilliseconds`` and ``AttitudeTimeTag`` the milliseconds since the first ping
(the file's millisecond clock). Each ping is preceded by an attitude packet (``HeaderType`` 3,
``XTFATTITUDEDATA``) of the same instant: its ``TimeTag`` is the ping's ``AttitudeTimeTag``, its
time ``SourceEpoch`` + ``EpochMicroseconds`` (and ``Year`` .. ``Second`` + ``Millisecond``), so a
reader that pairs them (pyxtf's ``get_time`` on the attitude packet) has every ping's time to the
microsecond, not only to the hundredth; its ``Heading`` is the ping's ``SensorHeading``. Per channel: ``SlantRange`` = ``range_max``, ``TimeDelay`` the
two-way time to ``range_min``, ``TimeDuration`` the two-way time of the window, ``SecondsPerPing``,
``NumSamples``, ``Frequency`` (kHz).
"""
from __future__ import annotations

import calendar
import datetime
import os
import struct

import numpy as np

from mitsonar._files import replacing

#: XTFHeaderType of a sonar (side-scan) and an attitude packet, and the ChanInfo TypeOfChannel codes.
SONAR, ATTITUDE, PORT_TYPE, STARBOARD_TYPE = 0, 3, 1, 2
NAV_LATLON = 3
KNOT = 1852.0 / 3600.0


class XTFError(ValueError):
    """A scan that cannot go into an XTF file: one line naming it and the field."""


def _layout(fields):
    return struct.Struct("<" + "".join(code for _, code in fields)), [name for name, _ in fields]


# Triton XTF rev 35+ structures, in file order (names as in the format document).
CHANINFO = _layout([
    ("TypeOfChannel", "B"), ("SubChannelNumber", "B"), ("CorrectionFlags", "H"), ("UniPolar", "H"),
    ("BytesPerSample", "H"), ("Reserved", "I"), ("ChannelName", "16s"), ("VoltScale", "f"), ("Frequency", "f"),
    ("HorizBeamAngle", "f"), ("TiltAngle", "f"), ("BeamWidth", "f"), ("OffsetX", "f"), ("OffsetY", "f"),
    ("OffsetZ", "f"), ("OffsetYaw", "f"), ("OffsetPitch", "f"), ("OffsetRoll", "f"), ("BeamsPerArray", "H"),
    ("SampleFormat", "B"), ("ReservedArea2", "53s")])
FILEHEADER = _layout([
    ("FileFormat", "B"), ("SystemType", "B"), ("RecordingProgramName", "8s"), ("RecordingProgramVersion", "8s"),
    ("SonarName", "16s"), ("SonarType", "H"), ("NoteString", "64s"), ("ThisFileName", "64s"), ("NavUnits", "H"),
    ("NumberOfSonarChannels", "H"), ("NumberOfBathymetryChannels", "H"), ("NumberOfSnippetChannels", "B"),
    ("NumberOfForwardLookArrays", "B"), ("NumberOfEchoStrengthChannels", "H"),
    ("NumberOfInterferometryChannels", "B"), ("Reserved1", "B"), ("Reserved2", "H"),
    ("ReferencePointHeight", "f"), ("ProjectionType", "12s"), ("SpheriodType", "10s"), ("NavigationLatency", "i"),
    ("OriginY", "f"), ("OriginX", "f"), ("NavOffsetY", "f"), ("NavOffsetX", "f"), ("NavOffsetZ", "f"),
    ("NavOffsetYaw", "f"), ("MRUOffsetY", "f"), ("MRUOffsetX", "f"), ("MRUOffsetZ", "f"), ("MRUOffsetYaw", "f"),
    ("MRUOffsetPitch", "f"), ("MRUOffsetRoll", "f")])
PINGHEADER = _layout([
    ("MagicNumber", "H"), ("HeaderType", "B"), ("SubChannelNumber", "B"), ("NumChansToFollow", "H"),
    ("Reserved1", "4s"), ("NumBytesThisRecord", "I"),
    ("Year", "H"), ("Month", "B"), ("Day", "B"), ("Hour", "B"), ("Minute", "B"), ("Second", "B"), ("HSeconds", "B"),
    ("JulianDay", "H"), ("EventNumber", "I"), ("PingNumber", "I"), ("SoundVelocity", "f"), ("OceanTide", "f"),
    ("Reserved2", "I"), ("ConductivityFreq", "f"), ("TemperatureFreq", "f"), ("PressureFreq", "f"),
    ("PressureTemp", "f"), ("Conductivity", "f"), ("WaterTemperature", "f"), ("Pressure", "f"),
    ("ComputedSoundVelocity", "f"), ("MagX", "f"), ("MagY", "f"), ("MagZ", "f"), ("AuxVal1", "f"), ("AuxVal2", "f"),
    ("AuxVal3", "f"), ("AuxVal4", "f"), ("AuxVal5", "f"), ("AuxVal6", "f"), ("SpeedLog", "f"), ("Turbidity", "f"),
    ("ShipSpeed", "f"), ("ShipGyro", "f"), ("ShipYcoordinate", "d"), ("ShipXcoordinate", "d"), ("ShipAltitude", "H"),
    ("ShipDepth", "H"), ("FixTimeHour", "B"), ("FixTimeMinute", "B"), ("FixTimeSecond", "B"),
    ("FixTimeHsecond", "B"), ("SensorSpeed", "f"), ("KP", "f"), ("SensorYcoordinate", "d"),
    ("SensorXcoordinate", "d"), ("SonarStatus", "H"), ("RangeToFish", "H"), ("BearingToFish", "H"),
    ("CableOut", "H"), ("Layback", "f"), ("CableTension", "f"), ("SensorDepth", "f"),
    ("SensorPrimaryAltitude", "f"), ("SensorAuxAltitude", "f"), ("SensorPitch", "f"), ("SensorRoll", "f"),
    ("SensorHeading", "f"), ("Heave", "f"), ("Yaw", "f"), ("AttitudeTimeTag", "I"), ("DOT", "f"),
    ("NavFixMilliseconds", "I"), ("ComputerClockHour", "B"), ("ComputerClockMinute", "B"),
    ("ComputerClockSecond", "B"), ("ComputerClockHsec", "B"), ("FishPositionDeltaX", "h"),
    ("FishPositionDeltaY", "h"), ("FishPositionErrorCode", "B"), ("OptionalOffset", "I"),
    ("CableOutHundredths", "B"), ("ReservedSpace2", "6s")])
PINGCHANHEADER = _layout([
    ("ChannelNumber", "H"), ("DownsampleMethod", "H"), ("SlantRange", "f"), ("GroundRange", "f"),
    ("TimeDelay", "f"), ("TimeDuration", "f"), ("SecondsPerPing", "f"), ("ProcessingFlags", "H"),
    ("Frequency", "H"), ("InitialGainCode", "H"), ("GainCode", "H"), ("BandWidth", "H"), ("ContactNumber", "I"),
    ("ContactClassification", "H"), ("ContactSubNumber", "B"), ("ContactType", "B"), ("NumSamples", "I"),
    ("MillivoltScale", "H"), ("ContactTimeOffTrack", "f"), ("ContactCloseNumber", "B"), ("Reserved2", "B"),
    ("FixedVSOP", "f"), ("Weight", "h"), ("ReservedSpace", "4s")])
ATTITUDEDATA = _layout([
    ("MagicNumber", "H"), ("HeaderType", "B"), ("SubChannelNumber", "B"), ("NumChansToFollow", "H"),
    ("Reserved1", "4s"), ("NumBytesThisRecord", "I"), ("Reserved2", "8s"), ("EpochMicroseconds", "I"),
    ("SourceEpoch", "I"), ("Pitch", "f"), ("Roll", "f"), ("Heave", "f"), ("Yaw", "f"), ("TimeTag", "I"),
    ("Heading", "f"), ("Year", "H"), ("Month", "B"), ("Day", "B"), ("Hour", "B"), ("Minute", "B"), ("Second", "B"),
    ("Millisecond", "H"), ("Reserved3", "1s")])
assert (CHANINFO[0].size, FILEHEADER[0].size, PINGHEADER[0].size, PINGCHANHEADER[0].size, ATTITUDEDATA[0].size) == \
    (128, 256, 256, 64, 64)


def _pack(layout, **values) -> bytes:
    st, names = layout
    unknown = set(values) - set(names)
    assert not unknown, unknown
    return st.pack(*(values.get(n, b"" if "s" in code else 0)
                     for n, code in zip(names, (c for c in _codes(st.format)))))


def _codes(fmt):
    """The struct codes of a format, one per field (``16s`` one code)."""
    out, num = [], ""
    for ch in fmt.lstrip("<"):
        if ch.isdigit():
            num += ch
        else:
            out.append(num + ch)
            num = ""
    return out


def check_scan(scan, name="scan") -> tuple[np.ndarray, np.ndarray]:
    """The port and starboard row indices of a side-scan ``scan`` with both channels, paired
    ping by ping; an `XTFError` naming ``name`` otherwise."""
    import mitsonar.kinds as kinds

    kind = kinds.kind_of(scan)
    if kind is None or not kind.sided:
        raise XTFError(f"{name}: 'kind' {scan.kind!r} is not allowed in an XTF export (a side-scan scan, "
                       f"kind {kinds.which('sided')}, with both channels)")
    ch = scan.channel
    port, stbd = np.flatnonzero(ch == 0), np.flatnonzero(ch == 1)
    if len(port) == 0 or len(port) != len(stbd):
        raise XTFError(f"{name}: meta 'side' {scan.meta.side or 'both'!r} with {len(port)} port and {len(stbd)} "
                       "starboard rows is not allowed in an XTF export (side 'both': as many port as starboard rows)")
    return port, stbd


def _utc(t):
    d = datetime.datetime(1970, 1, 1, tzinfo=datetime.timezone.utc) + datetime.timedelta(seconds=float(t))
    return d


class _Pings:
    """Every ping's fields, in the world frame, for all scans together (speed needs neighbours)."""

    def __init__(self, scans, names, start, trajectory):
        from mitsonar.export.ros.bag import scan_base
        from mitsonar.products.sidescan import first_return

        self.rows = []
        t, pos, fwd, alt = [], [], [], []
        for scan, name in zip(scans, names):
            port, stbd = check_scan(scan, name)
            base = scan_base(scan)
            times = np.zeros(scan.n_pings) if scan.times is None else np.asarray(scan.times, np.float64)
            t.append(base + times[port])
            pos.append(scan.poses[port, :3, 3])
            fwd.append(scan.poses[port, :3, 0])         # the port beam frame's +x: the head's forward
            a = first_return(scan) if np.any(scan.intensity > 0) else np.full(scan.n_pings, np.nan)
            alt.append(np.nan_to_num(a[port], nan=0.0))
            self.rows += [(scan, int(p), int(s)) for p, s in zip(port, stbd)]
        self.t, self.pos = np.concatenate(t), np.concatenate(pos)
        self.fwd, self.alt = np.concatenate(fwd), np.concatenate(alt)
        self.start = float(start)
        if trajectory is not None:
            lo, hi = trajectory.span
            here = trajectory.at(np.clip(self.t, lo, hi))
            ta, tb = np.clip(self.t - 0.05, lo, hi), np.clip(self.t + 0.05, lo, hi)
            a, b = trajectory.at(ta)[:, :3, 3], trajectory.at(tb)[:, :3, 3]
            vel = (b - a) / np.where(tb > ta, tb - ta, 1.0)[:, None]
            ship, self.ship_fwd = here[:, :3, 3], here[:, :3, 0]
        else:
            ship, self.ship_fwd = self.pos, self.fwd
            if len(self.t) > 1 and np.ptp(self.t) > 0:
                order = np.argsort(self.t, kind="stable")
                tt, uniq = np.unique(self.t[order], return_index=True)
                pp = self.pos[order][uniq]
                vel = np.zeros_like(self.pos)
                if len(tt) > 1:
                    for i in range(3):
                        vel[:, i] = np.interp(self.t, tt, np.gradient(pp[:, i], tt))
            else:
                vel = np.zeros_like(self.pos)
        self.ship = ship
        self.speed = np.hypot(vel[:, 0], vel[:, 1]) / KNOT


def write_xtf(path, scans, frame, *, names=None, start=0.0, trajectory=None, sonar_name="mitsonar") -> int:
    """Write side-scan ``scans`` (in time order) as one XTF file at ``path`` (under a temporary
    name, renamed when complete), navigation through ``frame`` (a `GeoFrame`); ``start`` seconds
    are added to every time (e.g. a Unix time), ``trajectory`` the vehicle's (ship position, gyro
    and speed). Every scan is checked before the file is opened. Returns the number of pings."""
    names = names or [f"scans[{i}]" for i in range(len(scans))]
    if not scans:
        raise XTFError("XTF export: no scans given (at least one side-scan scan)")
    types = sorted({str(np.asarray(s.data).dtype) for s in scans})
    if len(types) > 1:
        raise XTFError(f"XTF export: the scans' data are {' and '.join(types)}; allowed: one type in a file (its "
                       f"channels' BytesPerSample: bytes, or one A/D's uint16 or uint32 codes)")
    pings = _Pings(scans, names, start, trajectory)
    first = scans[0]
    slon, slat = frame.to_lonlat(pings.pos[:, 0], pings.pos[:, 1])
    blon, blat = frame.to_lonlat(pings.ship[:, 0], pings.ship[:, 1])
    heading = frame.true_heading(pings.pos[:, 0], pings.pos[:, 1], pings.fwd[:, 0], pings.fwd[:, 1])
    gyro = frame.true_heading(pings.ship[:, 0], pings.ship[:, 1], pings.ship_fwd[:, 0], pings.ship_fwd[:, 1])
    with replacing(path) as tmp, open(tmp, "wb") as f:
        f.write(_file_header(first, os.path.basename(os.fspath(path)), sonar_name, frame))
        t0 = pings.t.min() if len(pings.t) else 0.0
        for k, (scan, p, s) in enumerate(pings.rows):
            exact = _utc(pings.start + pings.t[k])
            ms = int(round(1000 * (pings.t[k] - t0)))
            f.write(_attitude(exact, ms, heading[k]))
            when = _utc(round(pings.start + pings.t[k], 2))      # the sonar packet holds hundredths
            chans = b"".join(_channel(scan, row, ch) for ch, row in ((0, p), (1, s)))
            size = PINGHEADER[0].size + len(chans)
            padded = (size + 63) // 64 * 64
            hsec = min(99, int(round(when.microsecond / 10000)))
            head = _pack(
                PINGHEADER, MagicNumber=0xFACE, HeaderType=SONAR, NumChansToFollow=2, NumBytesThisRecord=padded,
                Year=when.year, Month=when.month, Day=when.day, Hour=when.hour, Minute=when.minute,
                Second=when.second, HSeconds=hsec, JulianDay=when.timetuple().tm_yday, PingNumber=k,
                SoundVelocity=float(scan.sound_speed), ShipSpeed=pings.speed[k], ShipGyro=gyro[k],
                ShipYcoordinate=blat[k], ShipXcoordinate=blon[k], FixTimeHour=when.hour, FixTimeMinute=when.minute,
                FixTimeSecond=when.second, FixTimeHsecond=hsec, SensorSpeed=pings.speed[k],
                SensorYcoordinate=slat[k], SensorXcoordinate=slon[k], SensorDepth=-pings.pos[k, 2],
                SensorPrimaryAltitude=pings.alt[k], SensorHeading=heading[k], AttitudeTimeTag=ms,
                NavFixMilliseconds=ms, ComputerClockHour=when.hour, ComputerClockMinute=when.minute,
                ComputerClockSecond=when.second, ComputerClockHsec=hsec)
            f.write(head + chans + b"\0" * (padded - size))
    return len(pings.rows)


def _attitude(when, ms, heading) -> bytes:
    """The attitude packet of a ping at ``when`` (a UTC datetime): its time to the microsecond,
    ``TimeTag`` the ping's millisecond tag ``ms``, its heading."""
    epoch = max(0, calendar.timegm(when.timetuple()))
    return _pack(ATTITUDEDATA, MagicNumber=0xFACE, HeaderType=ATTITUDE, NumBytesThisRecord=ATTITUDEDATA[0].size,
                 EpochMicroseconds=when.microsecond, SourceEpoch=epoch, TimeTag=ms, Heading=float(heading),
                 Year=when.year, Month=when.month, Day=when.day, Hour=when.hour, Minute=when.minute,
                 Second=when.second, Millisecond=when.microsecond // 1000)


def _frequency_khz(scan):
    hz = scan.meta.frequency
    return 0.0 if hz is None else float(hz) / 1000.0


def _file_header(scan, filename, sonar_name, frame) -> bytes:
    chans = b""
    for i, (channel_type, name) in enumerate(((PORT_TYPE, b"port"), (STARBOARD_TYPE, b"starboard"))):
        chans += _pack(CHANINFO, TypeOfChannel=channel_type, SubChannelNumber=i, CorrectionFlags=1, UniPolar=1,
                       BytesPerSample=scan.data.dtype.itemsize, Reserved=scan.n_bins, ChannelName=name,
                       Frequency=_frequency_khz(scan), HorizBeamAngle=float(scan.beamwidth_v),
                       TiltAngle=float(scan.meta.depression or 0.0), BeamWidth=float(scan.beamwidth_h),
                       SampleFormat=SAMPLE_FORMATS[scan.data.dtype.itemsize])
    chans += b"".join(_pack(CHANINFO, Reserved=1024) for _ in range(4))
    head = _pack(FILEHEADER, FileFormat=0x7B, SystemType=1, RecordingProgramName=b"mitsonar",
                 RecordingProgramVersion=_version(), SonarName=sonar_name.encode()[:16], SonarType=0,
                 NoteString=f"simulated; grid {frame.crs}".encode()[:64], ThisFileName=filename.encode()[:64],
                 NavUnits=NAV_LATLON, NumberOfSonarChannels=2, ReferencePointHeight=float(frame.height))
    return head + chans


def _version() -> bytes:
    from mitsonar._version import __version__

    return __version__.encode()[:8]


#: CHANINFO ``SampleFormat`` by bytes a sample: 1-byte, 2-byte and 4-byte integers (XTF rev 41)
SAMPLE_FORMATS = {1: 8, 2: 3, 4: 2}


def _channel(scan, row, number) -> bytes:
    data = np.ascontiguousarray(scan.data[row], dtype=scan.data.dtype.newbyteorder("<"))
    c = float(scan.sound_speed)
    period = scan.meta.ping_period
    head = _pack(PINGCHANHEADER, ChannelNumber=number, SlantRange=float(scan.range_max),
                 TimeDelay=2.0 * float(scan.range_min) / c,
                 TimeDuration=2.0 * (float(scan.range_max) - float(scan.range_min)) / c,
                 SecondsPerPing=0.0 if period is None else float(period),
                 Frequency=min(65535, int(round(_frequency_khz(scan)))), NumSamples=data.size)
    return head + data.tobytes()




def check_xtf_output(path, force=False, folder_may_be=None) -> str:
    """The ``--xtf`` path, refused (one line, before any work) if it is not an ``.xtf`` file name
    that can be written, or exists without ``force``."""
    from mitsonar._files import check_output_file

    return check_output_file(path, XTFError, extensions=(".xtf",), force=force, folder_may_be=folder_may_be,
                             words={"directory": "--xtf {path}: is a folder; give an .xtf file name",
                                    "extension": "--xtf {path}: the file name must end in .xtf",
                                    "no_folder": "--xtf {path}: the folder {folder} does not exist"})


def frame_for(args, scans, names):
    """The `GeoFrame` of ``--origin``/``--crs``, else the one the scans' metadata holds (all the
    same), else an `XTFError` asking for ``--origin``."""
    from mitsonar.geometry.geodesy import GeoFrame, frame_from_args

    frame = frame_from_args(args)
    if frame is not None:
        return frame
    frames = [GeoFrame.from_meta(s.meta, f"{n}: meta") for s, n in zip(scans, names)]
    if frames and frames[0] is not None and all(f == frames[0] for f in frames):
        return frames[0]
    raise XTFError("--xtf: give --origin LAT LON [HEIGHT] (the scans' metadata hold no origin, or not the same "
                   "one): XTF navigation is in latitude and longitude")
