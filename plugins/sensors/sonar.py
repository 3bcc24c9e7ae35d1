"""The ``sonar`` sensor: a transducer with a beam pattern on a mechanically scanned head, a
multibeam (forward-looking) head whose rows are receive beams formed across one transmit fan, or a
side-scan head whose rows are its port and starboard channels' pings."""
from __future__ import annotations

import dataclasses
import math

import drjit as dr
import mitsuba as mi
import numpy as np

from mitsonar._checks import not_allowed
from mitsonar._limits import LIMITS, check
from mitsonar.acoustics.water import SOUND_SPEED
import mitsonar.kinds as kinds
from mitsonar.geometry.frames import SIDES, check_rigid, check_rigid_stack
from mitsonar.plugins.jit_arrays import upload
from mitsonar.plugins.props import count, number, text
from mitsonar.plugins.registry import register_plugin
from mitsonar.presets.sidescan import PRESETS
from mitsonar.plugins.water import check_pose, number_or_auto, read_water, resolve

from . import beam as patterns
from .beam import BeamPattern, read_beam_table, resolve_path

# The size bounds are `mitsonar._limits.LIMITS`, with the physics behind them.
MAX_BINS, MAX_PINGS = int(LIMITS["n_bins"].hi), int(LIMITS["n_pings"].hi)
DEFAULT_FREQUENCY = 700e3
# A side-scan head's transducers are tilted down this much unless the XML (or a preset) says.
DEFAULT_DEPRESSION = 15.0
#: The transducer's quality factor when neither the XML nor a preset gives a ``bandwidth``: the band is
#: ``frequency / DEFAULT_Q`` wide (+-25 %). Stansfield's optimum mechanical Q of a broadband projector,
#: ``Q_opt = 1.2 sqrt(1 - k_eff^2) / k_eff`` (Stansfield, *Underwater Electroacoustic Transducers*, 1991,
#: as used by Moffett et al., J. Acoust. Soc. Am. 121(5), 2007, doi:10.1121/1.2717496, whose
#: fractional bandwidth is about 1 / Q), is 2.1 for an effective coupling k_eff = 0.5, a PZT
#: transducer's (material k33 about 0.7, the effective coupling below it); single-crystal heads reach
#: Q = 1, narrowband resonant ones are higher: give their ``bandwidth``.
DEFAULT_Q = 2.0


class SonarSensor(mi.Sensor):
    """Imaging sonar head: a transducer with a beam pattern, pinging at a list of bearings.

    The beam frame (``to_world``) has +z on the boresight at bearing 0 and +y on the scan axis;
    ping ``k`` points at bearing ``bearing_start + k * bearing_step`` (degrees), a right-handed
    rotation of the beam frame about its +y axis. Range of an echo is half its path length.

    ``kind='mechanical'`` (MSIS, e.g. Tritech Micron): one monostatic beam, rotated ping by ping;
    the two-way gain of a direction is ``B(d)^2`` in that ping's frame. ``kind='multibeam'``
    (forward-looking sonar): one transmit fan fixed in the beam frame (``tx_*``) and one receive
    beam per row (``beam_pattern`` and ``beamwidth_*``, steered to the row's bearing); the two-way
    gain of row k is ``B_tx(d) B_rx(d in row k's frame)``. All rows share one pose.
    ``kind='sidescan'``: ``to_world`` is the head frame (x along track, y port, z up); two
    channels, port (boresight +y) and starboard (-y), each turned down about +x by ``depression``
    (`mitsonar.geometry.frames.sidescan_rotation`), each a monostatic beam like a mechanical head's
    (``beamwidth_h`` along track, the beam frame's azimuth; ``beamwidth_v`` the across-track fan, its
    elevation). ``side`` picks the channels: with ``both`` the rows are the ``n_pings`` port pings then
    the ``n_pings`` starboard pings (2 n_pings rows, `channels` says which is which), with one side
    row k is ping k. ``preset`` sets the defaults of a commercial head (`mitsonar.presets.sidescan.PRESETS`).
    ``kind='volumetric'`` (3D imaging sonar): a multibeam head whose receive beams form an
    ``n_elevation x n_azimuth`` grid (`mitsonar.kinds.Volumetric`): row ``k = i n_azimuth + j``
    is turned by bearing ``bearing_start + j bearing_step`` about +y, then by elevation
    ``elevation_start + i elevation_step`` towards +y; ``Scan.volume`` reshapes a frame to
    ``(n_elevation, n_azimuth, n_bins)``. ``sonar_tof`` traces its rows per row (no shared beams).

    Ping schedule: a mechanical head fires ping ``k`` at ``k * ping_period`` seconds from the scan
    start; a multibeam head fires all rows of a frame at once, and frames ``ping_period`` apart;
    a side-scan head fires both channels of ping ``k`` together at ``k * ping_period``.
    The default period is the two-way flight to ``range_max``, ``2 range_max / sound_speed``, plus
    the head's overhead (its kind's ``head_overhead``, `mitsonar.kinds`: 30 ms mechanical,
    50 ms multibeam, none side-scan).

    ``mi.render``'s paths per row are the ``<sampler>``'s ``sample_count``, 1 to 2^31 - 1.

    ================ ============ ===============================================================
    Parameter        Default      Meaning
    ================ ============ ===============================================================
    kind             mechanical   ``mechanical`` (mechanically scanned imaging sonar, MSIS),
                                  ``multibeam`` (rows = receive beams across one transmit fan),
                                  ``sidescan`` (rows = port then starboard pings) or
                                  ``volumetric`` (rows = beams over an elevation x azimuth grid)
    to_world         identity     beam frame in the world (rigid)
    range_min        0            m, start of the range window (0 to 100 km)
    range_max        12           m, end of the range window (echoes beyond are dropped);
                                  at most 100 km (`mitsonar._limits`: the bounds and why)
    n_bins           500          range bins between ``range_min`` and ``range_max`` (1 to
                                  65536)
    bearing_start    0            deg, bearing of the first ping (volumetric: the first
                                  column's azimuth)
    bearing_step     1.8          deg between pings (Micron: 200 steps per turn; volumetric:
                                  between the grid's columns)
    bearings         (none)       multibeam: the head's own table of beam bearings, deg, one per
                                  receive beam (comma- or space-separated, strictly increasing,
                                  each in [-180, 180]); sets ``n_pings``, and takes the place of
                                  ``bearing_start``/``bearing_step`` (refused with them)
    n_pings          200          pings in a scan (sidescan: per channel), 1 to 100000; a
                                  multibeam's receive beams, 1 to 4096 (volumetric: refused,
                                  the rows are ``n_elevation x n_azimuth``)
    n_azimuth        64           volumetric: the grid's columns (azimuths), 1 to 4096
    n_elevation      32           volumetric: the grid's rows (elevations), 1 to 4096; row
                                  ``k = i n_azimuth + j`` is elevation i, azimuth j, and the
                                  rows number at most 100000
    elevation_start  -15.5        volumetric: deg, the first grid row's elevation (towards +y);
                                  every row's inside (-90, 90) deg
    elevation_step   1            volumetric: deg between the grid's rows
    side             both         sidescan: ``port``, ``starboard`` or ``both`` channels
    depression       15           sidescan: deg, each channel's boresight below the horizontal
    preset           (none)       sidescan: a commercial head's defaults (``klein3000_100k``,
                                  ``klein3000_500k``, ``starfish450``; `mitsonar.presets.sidescan`)
    ping_period      physical     s between pings (multibeam: between frames); default
                                  ``2 range_max / sound_speed`` + 0.03 s (mechanical) or
                                  + 0.05 s (multibeam) or + 0 (sidescan); not less than the
                                  two-way flight, at most 3600 s
    beam_pattern     gaussian     ``gaussian``, ``sinc``, ``uniform`` or ``table``
    beamwidth_h      3            deg, full -3 dB one-way width across the scan plane
                                  (sidescan: along track, default 1)
    beamwidth_v      35           deg, full -3 dB one-way width along the scan axis
                                  (sidescan: the across-track fan, default 50)
    beam_table       (none)       CSV (axis, angle_deg, gain_db) for ``table``
    sound_speed      1500         m/s; or ``<string value="auto"/>``: Mackenzie (1981) at the
                                  head's depth ``surface_z - z`` (z of ``to_world``'s origin),
                                  UNESCO (Chen and Millero) outside Mackenzie's range
    absorption       0            dB/m, applied to the whole two-way path; or ``auto``: Francois
                                  and Garrison (1982) at ``frequency`` and the head's depth,
                                  Ainslie and McColm (1998) outside F&G's range
    frequency        700e3        Hz, the head's carrier: the centre of its band (``bandwidth``),
                                  the ``sinc`` pattern's and ``absorption`` ``auto``'s frequency
    bandwidth        frequency/Q  Hz, the transducer's band ``frequency +- bandwidth / 2``: the
                                  carriers `mitsonar.render_echoes` accepts; default a preset's
                                  published band, else ``frequency / DEFAULT_Q`` (Q = 2)
    elements         (none)       CSV of the receive elements' ``x,y,z`` rows (m, beam frame; a
                                  header line allowed), relative to the scene file; read and
                                  checked when the scene loads; `mitsonar.render_echoes` uses
                                  them when its ``elements`` is None (default: one element at
                                  the transmitter)
    temperature      10           deg C, the water (only with ``auto``; absorption -6 to 35,
                                  sound speed -2 to 40)
    salinity         35           ppt, the water (only with ``auto``; absorption 5 to 50,
                                  sound speed 0 to 40)
    ph               8            pH of the water (``absorption`` ``auto``; 7.7 to 8.3)
    surface_z        0            m, world z of the sea surface (only with ``auto``); a
                                  render given a ``pose`` (trajectory) refuses ``auto``
    tx_pattern       gaussian     multibeam transmit fan: ``gaussian``, ``sinc`` or ``uniform``
    tx_beamwidth_h   swath        deg, full -3 dB width of the fan across the swath; default the
                                  swath, ``|bearing_step| (n_pings - 1) + beamwidth_h``
    tx_beamwidth_v   beamwidth_v  deg, full -3 dB width of the fan along the scan axis
                                  (volumetric: the elevation span, ``|elevation_step|
                                  (n_elevation - 1) + beamwidth_v``)
    aperture_h/_v    derived      m (``sinc``); from the beam widths when absent
    electronics      see below    the fields of ``mitsonar.receiver.electronics.Electronics``
                                  (``source_level`` in dB re 1 uPa at 1 m,
                                  ``receiver_sensitivity``, ``noise_level``, ``tvg``, ``gain``, ...)
    ================ ============ ===============================================================
    """

    @classmethod
    def parameters(cls) -> list:
        """The XML parameter names: the table above, with the electronics' fields by name."""
        from mitsonar.receiver.electronics import Electronics

        from mitsonar.plugins.props import table_parameters

        return ([n for n in table_parameters(cls.__doc__) if n != "electronics"]
                + [f.name for f in dataclasses.fields(Electronics)])

    def __init__(self, props: mi.Properties):
        num = lambda name, default: number(props, name, default, "sonar")  # noqa: E731
        self.n_bins = count(props, "n_bins", 500, "sonar")
        self.kind = text(props, "kind", kinds.DEFAULT, "sonar")
        self.sonar_kind = kinds.lookup(self.kind)     # what differs between kinds is asked of it
        if self.sonar_kind is None:
            raise not_allowed("sonar", "kind", self.kind, "one of " + ", ".join(kinds.names()))
        preset = self._sidescan(props)
        self._grid(props)
        self.bearing_table = self._bearing_table(props)
        if self.bearing_table is not None:
            self.pings = len(self.bearing_table)
        else:
            self.pings = count(props, "n_pings", 200, "sonar") if self.n_azimuth is None else \
                self.n_azimuth * self.n_elevation
        # Checked before the film is made: without one, Mitsuba makes its default RGB film and
        # prints a warning above our error.
        for name in ("n_bins", "n_pings"):
            check("sonar", name, self.n_bins if name == "n_bins" else self.pings)
        if self.n_azimuth is None:
            self.n_azimuth, self.n_elevation = self.pings, 1   # one fan (or one ping per row)
        elif self.sonar_kind.transmit_fan:   # a grid's beams: each axis within a multibeam's count
            for name in ("n_azimuth", "n_elevation"):
                check("sonar", name, getattr(self, name), "n_beams", suffix=f" for kind {self.kind!r}")
        if self.sonar_kind.transmit_fan and not self.sonar_kind.grid:   # receive beams formed across one fan
            check("sonar", "n_pings", self.pings, "n_beams", suffix=f" for kind {self.kind!r}")
        # The rows of a scan: a side-scan head with both channels has two per ping.
        self.n_pings = self.pings * (2 if self.side == "both" else 1)
        if "film" not in props:
            # The film is the scan's range-intensity image: one row per ping, one column per bin.
            props["film"] = mi.load_dict({"type": "hdrfilm", "width": self.n_bins, "height": self.n_pings,
                                          "pixel_format": "luminance", "rfilter": {"type": "box"}})
        super().__init__(props)
        # the paths per ping of ``mi.render`` (its <sampler>'s sample_count): a 32-bit sample index
        check("sonar", "sample_count", int(self.sampler().sample_count()), "spp")
        self.range_min = num("range_min", 0.0)
        self.range_max = num("range_max", preset.get("range_max", 12.0))
        if self.bearing_table is None:
            self.bearing_start = num("bearing_start", 0.0)
            self.bearing_step = num("bearing_step", 1.8)
        else:   # the first bearing, and the mean step (what a swath or a window asks of a table)
            t = self.bearing_table
            self.bearing_start = float(t[0])
            self.bearing_step = float((t[-1] - t[0]) / (len(t) - 1)) if len(t) > 1 else 0.0
        # A number, or 'auto': the water's equations at the head's depth (plugins/water.py).
        self.sound_speed = number_or_auto(props, "sound_speed", SOUND_SPEED)
        self.absorption = number_or_auto(props, "absorption", 0.0)
        self.water = read_water(props, self.absorption, self.sound_speed)
        self.water_auto = [n for n in ("absorption", "sound_speed") if getattr(self, n) == "auto"]
        self.ping_period = num("ping_period", None)
        pattern = text(props, "beam_pattern", preset.get("beam_pattern", patterns.DEFAULT), "sonar")
        beam = self.sonar_kind.default_beamwidths
        bw_h = num("beamwidth_h", preset.get("beamwidth_h", beam[0]))
        bw_v = num("beamwidth_v", preset.get("beamwidth_v", beam[1]))
        table_path = text(props, "beam_table", "", "sonar")
        frequency = num("frequency", None)
        if frequency is None:
            frequency = preset.get("frequency")
        ap_h = num("aperture_h", None)
        ap_v = num("aperture_v", None)
        head_z = float(np.array(self.world_transform().matrix, dtype=np.float64).reshape(4, 4)[2, 3])
        self.absorption, self.sound_speed = resolve(
            self.water, self.absorption, self.sound_speed,
            frequency if frequency is not None else preset.get("frequency", DEFAULT_FREQUENCY), head_z)
        tx = {k: num(k, None) for k in ("tx_beamwidth_h", "tx_beamwidth_v") if k in props}
        if "tx_pattern" in props:
            tx["tx_pattern"] = text(props, "tx_pattern", None, "sonar")

        from mitsonar.receiver.electronics import Electronics, check_head_settings
        read = {"float": number, "int": count, "str": text}
        elec = {}
        for f in dataclasses.fields(Electronics):
            if f.name in props:
                field_type = f.type if isinstance(f.type, str) else f.type.__name__
                elec[f.name] = read[field_type](props, f.name, None, "sonar")
            elif f.name in preset:   # a side-scan preset's source level, sensitivity, noise
                elec[f.name] = preset[f.name]
        self.electronics = elec
        self._check()
        check_head_settings(elec, "sonar")             # the head's ranges, then the model's checks
        self.electronics_model = Electronics(**elec)

        shape = patterns.lookup(pattern)
        measured = shape is not None and shape.measured
        table = read_beam_table(table_path) if measured and table_path else None
        if table_path and not measured:
            raise ValueError(f"sonar 'beam_table' is only used with beam_pattern {patterns.which('measured')} "
                             f"(got {pattern!r})")
        self.beam = BeamPattern(pattern, bw_h, bw_v, DEFAULT_FREQUENCY if frequency is None else frequency,
                                ap_h, ap_v, self.sound_speed, table)
        self._tx_props = dict(tx)   # kept: a fan derived from the beam's widths follows them (parameters_changed)
        self.transmit = self._transmit(tx, bw_h, bw_v, self.beam.frequency)
        self.bandwidth = num("bandwidth", preset.get("bandwidth", self.beam.frequency / DEFAULT_Q))
        if not (math.isfinite(self.bandwidth) and 0.0 < self.bandwidth < 2.0 * self.beam.frequency):
            raise not_allowed("sonar", "bandwidth", self.bandwidth, f"a band > 0 Hz and below 2 frequency = "
                              f"{2.0 * self.beam.frequency:.0f} Hz: the band is frequency +- bandwidth / 2")
        self.elements_file = text(props, "elements", None, "sonar")
        self.elements = None if self.elements_file is None else read_head_elements(self.elements_file)
        self.beam_table = table_path
        self.to_world_np = check_rigid(np.array(self.world_transform().matrix, dtype=np.float64).reshape(4, 4))

    def _sidescan(self, props) -> dict:
        """Read and check the side-scan parameters (``side``, ``depression``, ``preset``), refused
        with any other kind; returns the preset's defaults ({} without one)."""
        names = ("side", "depression", "preset")
        if not self.sonar_kind.sided:
            given = [n for n in names if n in props]
            if given:
                raise ValueError(f"sonar '{given[0]}': only used with kind {kinds.which('sided')} "
                                 f"(kind is {self.kind!r})")
            self.side, self.depression, self.preset = None, None, None
            return {}
        for name in ("bearing_start", "bearing_step"):
            if name in props and not self.sonar_kind.steered:
                raise ValueError(f"sonar '{name}': not used with kind {self.kind!r} (its channels look port and "
                                 "starboard: set 'side' and 'depression')")
        name = text(props, "preset", None, "sonar")
        if name is not None and name not in PRESETS:
            raise not_allowed("sonar", "preset", name, "one of " + ", ".join(PRESETS))
        preset = PRESETS.get(name, {})
        self.preset = name
        self.side = text(props, "side", "both", "sonar")
        if self.side not in SIDES:
            raise not_allowed("sonar", "side", self.side, "one of " + ", ".join(SIDES))
        self.depression = number(props, "depression", preset.get("depression", DEFAULT_DEPRESSION), "sonar")
        if not (math.isfinite(self.depression) and 0.0 <= self.depression <= 90.0):
            raise not_allowed("sonar", "depression", self.depression, "an angle from 0 to 90 deg below the horizontal")
        return preset

    def _grid(self, props):
        """Read the elevation x azimuth grid of a kind whose rows are one (``n_azimuth``,
        ``n_elevation``, ``elevation_start``, ``elevation_step``; ``n_pings`` is then refused: the
        rows are the grid's), refused with any other kind. ``n_azimuth`` None without a grid."""
        names = ("n_azimuth", "n_elevation", "elevation_start", "elevation_step")
        self.elevation_start, self.elevation_step = 0.0, 0.0
        if not self.sonar_kind.grid:
            given = [n for n in names if n in props]
            if given:
                raise ValueError(f"sonar '{given[0]}': only used with kind {kinds.which('grid')} "
                                 f"(kind is {self.kind!r})")
            self.n_azimuth = self.n_elevation = None
            return
        if "n_pings" in props:
            raise ValueError(f"sonar 'n_pings': not used with kind {self.kind!r} (its rows are the beam grid: set "
                             "'n_azimuth' and 'n_elevation')")
        self.n_azimuth = count(props, "n_azimuth", 64, "sonar")
        self.n_elevation = count(props, "n_elevation", 32, "sonar")
        self.elevation_start = number(props, "elevation_start", -15.5, "sonar")
        self.elevation_step = number(props, "elevation_step", 1.0, "sonar")
        last = self.elevation_start + (self.n_elevation - 1) * self.elevation_step
        for name, value in (("elevation_start", self.elevation_start), ("elevation_step", last)):
            if not (math.isfinite(value) and abs(value) < 90.0):
                raise not_allowed("sonar", name, getattr(self, name), "elevations inside (-90, 90) deg: "
                                  "elevation_start + (n_elevation - 1) elevation_step = "
                                  f"{last:g} deg for the last row")

    def _bearing_table(self, props):
        """The XML ``bearings`` (deg, float64), checked; None without one. Only a
        ``transmit_fan`` kind takes one, and not with ``bearing_start``, ``bearing_step`` or
        ``n_pings`` (the table says them all)."""
        if "bearings" not in props:
            return None
        raw = text(props, "bearings", "", "sonar")
        if not self.sonar_kind.transmit_fan or self.sonar_kind.grid:
            raise ValueError(f"sonar 'bearings': only used with kind {kinds.which('transmit_fan')} "
                             f"(kind is {self.kind!r})")
        given = [n for n in ("bearing_start", "bearing_step", "n_pings") if n in props]
        if given:
            raise ValueError(f"sonar '{given[0]}': not used with 'bearings' (the table gives every beam's bearing "
                             "and their number)")
        allowed = "a comma- or space-separated list of strictly increasing bearings in [-180, 180] deg"
        try:
            table = np.array([float(v) for v in raw.replace(",", " ").split()], dtype=np.float64)
        except ValueError:
            raise not_allowed("sonar", "bearings", raw[:60], allowed) from None
        if (table.size == 0 or not np.all(np.isfinite(table)) or np.any(np.abs(table) > 180.0)
                or np.any(np.diff(table) <= 0)):
            raise not_allowed("sonar", "bearings", raw[:60], allowed)
        check("sonar", "n_pings", int(table.size), "n_beams", suffix=f" for kind {self.kind!r}")
        return table

    def _check(self):
        def bad(name, value, allowed):
            raise not_allowed("sonar", name, value, allowed)
        check("sonar", "range_min", self.range_min)
        check("sonar", "range_max", self.range_max, lo=self.range_min, lo_open=True,
              lo_text=f"a range > range_min = {self.range_min:g} m")
        # Bearings are angles: beyond a turn they only lose precision (1e30 + k * 1.8 is one bearing).
        for name in ("bearing_start", "bearing_step"):
            if not (math.isfinite(getattr(self, name)) and abs(getattr(self, name)) <= 360.0):
                bad(name, getattr(self, name), "an angle in [-360, 360] deg")
        swath = self.swath_deg()
        top = self.sonar_kind.max_swath
        if top is not None and swath > top:
            bad("bearing_step", self.bearing_step, f"for kind {self.kind!r} the receive beams span |bearing_step| "
                f"x (n_pings - 1) <= {top:g} deg, here {swath:g} deg")
        if not (math.isfinite(self.sound_speed) and 1000.0 <= self.sound_speed <= 2000.0):
            bad("sound_speed", self.sound_speed, "1000 to 2000 m/s for water")
        if not (math.isfinite(self.absorption) and self.absorption >= 0):
            bad("absorption", self.absorption, "a finite attenuation >= 0 dB/m")
        flight = 2.0 * self.range_max / self.sound_speed
        if self.ping_period is None:
            self.ping_period = flight + self.sonar_kind.head_overhead
        else:
            check("sonar", "ping_period", self.ping_period, lo=flight,
                  lo_text=f"seconds from the two-way flight to range_max, 2 range_max / sound_speed = {flight:.6g} s")

    def _transmit(self, tx, bw_h, bw_v, frequency):
        """The multibeam transmit fan (None for a mechanical head, whose beam transmits itself)."""
        if not self.sonar_kind.transmit_fan:
            if tx:
                raise ValueError(f"sonar '{sorted(tx)[0]}': only used with kind {kinds.which('transmit_fan')} "
                                 f"(kind is {self.kind!r})")
            return None
        pattern = tx.get("tx_pattern", patterns.DEFAULT)
        if pattern not in patterns.names(transmits=True):
            raise not_allowed("sonar", "tx_pattern", pattern, f"one of {', '.join(patterns.names(transmits=True))}")
        swath = self.swath_deg() + bw_h
        h = float(tx.get("tx_beamwidth_h", min(swath, 360.0)))
        v = float(tx.get("tx_beamwidth_v", min(abs(self.elevation_step) * (self.n_elevation - 1) + bw_v, 180.0)))
        for name, value, hi in (("tx_beamwidth_h", h, 360.0), ("tx_beamwidth_v", v, 180.0)):
            if not (math.isfinite(value) and 0.0 < value <= hi):
                raise not_allowed("sonar", name, value, f"a width in (0, {hi:g}] deg")
        return BeamPattern(pattern, h, v, frequency, None, None, self.sound_speed, source="sonar tx")

    # ------------------------------------------------------------------ geometry
    @property
    def bin_width(self) -> float:
        return (self.range_max - self.range_min) / self.n_bins

    def bin_centres(self) -> np.ndarray:
        return self.range_min + (np.arange(self.n_bins) + 0.5) * self.bin_width

    def bearings_deg(self) -> np.ndarray:
        """(n_pings,) deg: each row's bearing, the XML ``bearings`` table or the kind's
        ``bearing_start + k bearing_step`` (a grid's row i n_azimuth + j: azimuth j)."""
        if self.bearing_table is not None:
            return self.bearing_table.copy()
        if self.sonar_kind.grid:
            return self.sonar_kind.bearings_deg(self.bearing_start, self.bearing_step, self.n_pings, self.n_azimuth)
        return self.sonar_kind.bearings_deg(self.bearing_start, self.bearing_step, self.n_pings)

    def elevations_deg(self) -> np.ndarray:
        """(n_pings,) deg: each row's elevation (zeros but for a grid's rows: row i n_azimuth + j at
        ``elevation_start + i elevation_step``)."""
        return self.sonar_kind.elevations_deg(self.elevation_start, self.elevation_step, self.n_pings,
                                              self.n_azimuth)

    def swath_deg(self) -> float:
        """deg from the first column's bearing to the last one's (the table's span with ``bearings``)."""
        if self.bearing_table is not None:
            return float(self.bearing_table[-1] - self.bearing_table[0])
        return abs(self.bearing_step) * (self.n_azimuth - 1)

    def channels(self) -> np.ndarray:
        """(n_pings,) channel of each row of a side-scan head (0 port, 1 starboard): the port pings,
        then the starboard pings with ``side='both'``. None for the other kinds."""
        return self.sonar_kind.channels(self.side, self.pings)

    def ping_times(self) -> np.ndarray:
        """(n_pings,) seconds of each row's ping from the scan start: ``k * ping_period`` for a
        mechanical head and for each channel of a side-scan head (both channels of ping k fire
        together), zeros for the rows of a multibeam frame (fired together)."""
        return self.sonar_kind.ping_times(self.ping_period, self.pings, self.n_pings)

    @property
    def scan_period(self) -> float:
        """Seconds from one scan's start to the next one's: ``n_pings`` pings of a mechanical or a
        side-scan head (``n_pings`` per channel), one frame of a multibeam head."""
        return self.sonar_kind.scan_period(self.ping_period, self.pings)

    def head_pose(self, pose=None) -> np.ndarray:
        """The head's beam frame at bearing 0: ``to_world``, or a render's ``pose`` (checked rigid):
        one 4x4, or one per row, (n_pings, 4, 4), for a head on a moving platform."""
        if pose is None:
            return self.to_world_np
        check_pose(self.water_auto, pose)
        m = np.asarray(pose, dtype=np.float64)
        if m.ndim == 3:
            if m.shape != (self.n_pings, 4, 4):
                raise ValueError(f"render_scan 'pose': per-row poses must have shape "
                                 f"(n_pings, 4, 4) = {(self.n_pings, 4, 4)}, got {m.shape}")
            return check_rigid_stack(m, "render_scan 'pose'")
        return check_rigid(m, "render_scan 'pose'")

    def ping_poses(self, pose=None) -> np.ndarray:
        """(n_pings, 4, 4) world transform of each ping's beam frame (float64): the head pose (or
        row k's head pose) @ the rotation to row k's bearing (side-scan: to row k's channel;
        volumetric: to row k's bearing, then its elevation)."""
        el = self.elevations_deg() if self.sonar_kind.grid else None
        return self.head_pose(pose) @ self.sonar_kind.rotations(self.bearings_deg(), self.channels(), self.depression,
                                                                *(() if el is None else (el,)))

    def connection(self, pose=None):
        """What weights an echo's connection back to the transducer, for `SonarIntegrator.sample`.

        None for a mechanical head (its own beam, in the ping's frame). For a multibeam head, the
        transmit fan in the head's frame, one copy per row: paths start from the row's receive beam
        and connect back through the fan, which gives the same two-way gain and path lengths as
        transmitting through the fan and receiving in the row (reciprocity; the acoustic BSDF is
        symmetric), with importance sampling from the narrow beam. With per-row head poses, row k's
        fan is at row k's head pose.
        """
        if self.transmit is None:
            return None
        heads = self.head_pose(pose)
        return PingFrames(np.broadcast_to(heads, (self.n_pings, 4, 4))), self.transmit

    # ------------------------------------------------------------------ Mitsuba interface
    def sample_ray(self, time, sample1, sample2, sample3, active=True):
        """A ray of ping ``floor(sample2.y * n_pings)`` with direction drawn from the beam; weight B/pdf."""
        poses = self.ping_poses()
        ping = mi.UInt32(dr.clip(mi.UInt32(sample2.y * self.n_pings), 0, self.n_pings - 1))
        frame = PingFrames(poses)
        d, w = self.beam.sample(sample3, active)
        o, dw = frame.origin(ping), frame.to_world(ping, d)
        return mi.Ray3f(o, dw, time), mi.Spectrum(w)

    # ------------------------------------------------------------------ differentiable parameters
    def traverse(self, callback):
        """Expose to ``mi.traverse``, all differentiable (``mitsonar.plugins.integrators.paths.path_replay``):
        ``to_world`` (the head's beam frame, a ``mi.Transform4f``), ``absorption`` (dB/m) and, for a
        ``gaussian`` beam, ``beamwidth_h`` and ``beamwidth_v`` (deg)."""
        super().traverse(callback)
        for name, value in self.differentiable().items():
            callback.put(name, value, mi.ParamFlags.Differentiable)

    def differentiable(self) -> dict:
        """The sensor's traversed parameters by name (made on first use, kept: ``mi.traverse``
        hands out these very objects, so ``dr.enable_grad`` on them reaches the renders)."""
        if getattr(self, "_diff", None) is None:
            self._diff = {"to_world": mi.Transform4f(mi.Matrix4f(self.to_world_np)),
                          "absorption": mi.Float(self.absorption)}
            if self.beam.shape.traversed_widths:
                self._diff["beamwidth_h"] = mi.Float(self.beam.beamwidth_h)
                self._diff["beamwidth_v"] = mi.Float(self.beam.beamwidth_v)
        return self._diff

    def parameters_changed(self, keys):
        """Take new values of the traversed parameters, checked as in the XML (rigid ``to_world``,
        ``absorption`` >= 0, widths in (0, 360] x (0, 180] deg); the beam's sampling table is rebuilt
        for new widths, and so is a multibeam's transmit fan where its widths follow the beam's (no
        ``tx_beamwidth_h``/``tx_beamwidth_v`` in the XML): the scene then renders as one loaded with
        the new widths. Gradients with respect to the widths are the receive beam's (the fan's
        dependence on them is not differentiated)."""
        d = self.differentiable()
        if "to_world" in keys:
            m = np.array(d["to_world"].matrix, dtype=np.float64).reshape(4, 4)
            self.to_world_np = check_rigid(m, "sonar 'to_world'")
        if "absorption" in keys:
            value = float(d["absorption"][0])
            if not (math.isfinite(value) and value >= 0):
                raise not_allowed("sonar", "absorption", value, "a finite attenuation >= 0 dB/m")
            self.absorption = value
        if "beamwidth_h" in keys or "beamwidth_v" in keys:
            h, v = float(d["beamwidth_h"][0]), float(d["beamwidth_v"][0])
            self.beam = BeamPattern(self.beam.pattern, h, v, self.beam.frequency, None, None, self.sound_speed)
            if self.transmit is not None:
                # a multibeam's fan whose widths the XML left to the beam's (the swath plus one beam
                # width across, the beam's height) follows them, as loading those widths would do
                self.transmit = self._transmit(self._tx_props, h, v, self.beam.frequency)
        super().parameters_changed(keys)

    def to_string(self):
        tx = "" if self.transmit is None else (f", tx={self.transmit.pattern} "
                                               f"{self.transmit.beamwidth_h:g}x{self.transmit.beamwidth_v:g} deg")
        if self.sonar_kind.sided:
            tx = f", side={self.side}, depression={self.depression:g} deg"
        return (f"SonarSensor[kind={self.kind}, n_pings={self.n_pings}, n_bins={self.n_bins}, "
                f"range=[{self.range_min:g}, {self.range_max:g}) m, beam={self.beam.pattern} "
                f"{self.beam.beamwidth_h:g}x{self.beam.beamwidth_v:g} deg{tx}]")


def read_head_elements(path: str) -> np.ndarray:
    """(n, 3) m: the XML ``elements`` CSV (a relative path from the scene file's folder first, as
    ``beam_table``), read and checked by `mitsonar.geometry.elements.read_elements`."""
    import os

    from mitsonar.geometry.elements import read_elements

    found, tried = resolve_path(path)
    if found is None or os.path.isdir(found):
        raise ValueError(f"sonar 'elements': {path!r} is not allowed (a CSV file of x,y,z rows in m; tried "
                         f"{', '.join(tried)})")
    return read_elements(found, f"sonar (elements file {found})")


class PingFrames:
    """Per-ping beam frames uploaded once per render (opaque arrays: a new pose never recompiles)."""

    def __init__(self, poses: np.ndarray):
        poses = np.asarray(poses)
        self.x, self.y, self.z, self.p = (upload(mi.Float, poses[:, :3, c], np.float32) for c in range(4))

    def gather(self, ping):
        return (dr.gather(mi.Vector3f, self.x, ping), dr.gather(mi.Vector3f, self.y, ping),
                dr.gather(mi.Vector3f, self.z, ping), dr.gather(mi.Point3f, self.p, ping))

    def origin(self, ping):
        return dr.gather(mi.Point3f, self.p, ping)

    def to_world(self, ping, d):
        x, y, z, _ = self.gather(ping)
        return x * d.x + y * d.y + z * d.z


register_plugin("sensor", "sonar", SonarSensor)
