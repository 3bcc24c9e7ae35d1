"""Echo-sounder presets: downward bathymetric multibeams and an altimeter, as ``sonar`` sensors.

A bathymetric multibeam echo sounder (MBES) is the ``multibeam`` kind of the ``sonar`` sensor
looking down: its beam frame's boresight (+z) points down, its scan axis (+y) along the track
(vehicle +x), so the bearing of receive beam ``k`` is its across-track beam angle, positive to
port (the beam frame's +x is the vehicle's +y). A Mills-cross head is modelled as

* one transmit fan (``tx_*``): narrow along track (``tx_along``, the published along-track
  width), wide across it (a gaussian 1.5 times the swath: -1.3 dB one way at the outer beams);
* ``n_beams`` receive beams, narrow across track (``rx_across``, the published across-track
  width) at equal angles from ``-swath / 2`` to ``+swath / 2`` (the swath is the angle between the
  outermost beams' centres), and wide along track (``rx_along``: 4 times the transmit's along-track
  width, a simulation choice; the two-way along-track -3 dB width is then
  ``1 / sqrt(1 + 1/16) = 0.97`` of the transmit's, the published figure).

The altimeter (single-beam echo sounder) is one ping of a ``mechanical`` head that does not
rotate: one conical gaussian beam looking down.

The published figures of each head (frequency, beam count, beam widths, swath, source level), with
their sources, are `mitsonar.presets.echosounders`. The range bin (``bin_width``) is a simulation
choice near the heads' range resolution ``c / (2 bandwidth)`` (1.25 cm for a 60 kHz bandwidth), not a published figure. The
multibeams' ``pulse_length`` (an electronics field of the sensor) is the matched pulse of that
resolution, ``2 bin / c`` = 16.7 us at the preset's bin: the scene's speckle grains
(`mitsonar.receiver.speckle`, ``max(c pulse_length / 2, bin)`` long) are then one range resolution long,
not the Micron default pulse's 7.5 cm. The altimeter keeps the default electronics.

    from mitsonar.scenes.echosounders import sonar_xml
    xml = sonar_xml("r2sonic_2024", swath=130, range_max=30)    # a <sensor type="sonar"> element
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from mitsonar._checks import is_number, not_allowed
from mitsonar._limits import LIMITS, check
from mitsonar.acoustics.water import SOUND_SPEED
from mitsonar.presets.echosounders import PRESETS, WHERE, EchoSounder, preset  # noqa: F401 (this room's names)
from mitsonar.sonar_equation.levels import CALIBRATION_DB

#: The widest fan a bathymetric head may have: beyond 180 deg its outer beams look up.
MAX_SWATH = 180.0
#: Receive beams' along-track width over the transmit's (see the module docstring).
RX_ALONG_FACTOR = 4.0
#: Transmit fan's across-track gaussian width over the swath.
TX_ACROSS_FACTOR = 1.5
MAX_BINS = int(LIMITS["n_bins"].hi)   # the sensor's bound (`mitsonar._limits`)


def looking_down(position=(0.0, 0.0, 0.0)) -> np.ndarray:
    """The mount of a head looking straight down from ``position`` (vehicle frame, x forward,
    y port, z up): boresight -z, scan axis +x (along track), beam frame +x = port."""
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = (0.0, 1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, -1.0)
    m[:3, 3] = position
    return m


@dataclasses.dataclass(frozen=True)
class HeadSetup:
    """What `configure` made of a preset and its overrides: the sensor's parameters."""

    sounder: EchoSounder
    params: dict
    mount: np.ndarray

    @property
    def beam_angles(self) -> np.ndarray:
        """(n_beams,) degrees: each beam's across-track angle from the vertical, positive to port."""
        p = self.params
        return p["bearing_start"] + np.arange(p["n_pings"]) * p["bearing_step"]


def configure(name, *, swath=None, n_beams=None, range_min=None, range_max=None, bin_width=None,
              n_bins=None, mount=None, sound_speed=SOUND_SPEED) -> HeadSetup:
    """The ``sonar`` sensor parameters of preset ``name`` with the given overrides.

    ============ ===================================================================================
    swath        deg between the outermost beams' centres, within the head's range and at most
                 180 (multibeam only)
    n_beams      receive beams (multibeam only; default the preset's)
    range_min    m, start of the range window (default 0.1 for the altimeter, 0.5 else)
    range_max    m, end of the window (default the preset's)
    bin_width    m (default the preset's); or ``n_bins`` directly
    mount        4x4 rigid mount in the vehicle frame (default `looking_down`)
    ============ ===================================================================================

    Every value is checked here, with one line naming it, before any scene is made.
    """
    s = preset(name)

    def bad(field, value, allowed):
        raise not_allowed(WHERE, field, value, allowed)

    multibeam = s.kind.transmit_fan      # an MBES: receive beams across a transmit fan
    if not multibeam:
        for field, value in (("swath", swath), ("n_beams", n_beams)):
            if value is not None:
                bad(field, value, f"not used by the single-beam {s.model}")
    swath = s.swath if swath is None else swath
    lo, hi = s.swath_range
    if multibeam and not (is_number(swath) and 0 < swath <= MAX_SWATH):
        bad("swath", swath, f"a fan of at most {MAX_SWATH:g} deg across track; {s.model}: {lo:g} to {hi:g} deg")
    if multibeam and not lo <= swath <= hi:
        bad("swath", swath, f"{lo:g} to {hi:g} deg for the {s.model}")
    n_beams = s.n_beams if n_beams is None else n_beams
    check(WHERE, "n_beams", n_beams, lo=2 if multibeam else None)
    range_min = (0.1 if not multibeam else 0.5) if range_min is None else range_min
    range_max = s.range_max if range_max is None else range_max
    check(WHERE, "range_min", range_min)
    check(WHERE, "range_max", range_max, lo=range_min, lo_open=True, lo_text=f"a range > range_min = {range_min:g} m")
    if n_bins is None:
        bin_width = s.bin_width if bin_width is None else bin_width
        if not (is_number(bin_width) and bin_width > 0):
            bad("bin_width", bin_width, "a bin width > 0 m")
        n_bins = int(math.ceil((range_max - range_min) / bin_width - 1e-9))
        if n_bins > MAX_BINS:
            bad("bin_width", bin_width, f"at least {(range_max - range_min) / MAX_BINS:.3g} m for a "
                f"{range_max - range_min:g} m window (at most {MAX_BINS} bins)")
    else:
        check(WHERE, "n_bins", n_bins)
    mount = looking_down() if mount is None else np.asarray(mount, dtype=np.float64)
    from mitsonar.geometry.frames import check_rigid

    check_rigid(mount, f"{WHERE} 'mount'")
    params = dict(range_min=float(range_min), range_max=float(range_max), n_bins=int(n_bins),
                  sound_speed=float(sound_speed), beam_pattern="gaussian", source_level=s.source_level,
                  receiver_sensitivity=CALIBRATION_DB - s.source_level, noise_level=s.noise_level)
    if multibeam:
        n = int(n_beams)
        params.update(kind=s.kind.name, n_pings=n, bearing_start=-swath / 2.0, bearing_step=swath / (n - 1),
                      beamwidth_h=s.rx_across, beamwidth_v=RX_ALONG_FACTOR * s.tx_along,
                      tx_pattern="gaussian", tx_beamwidth_h=min(TX_ACROSS_FACTOR * swath, 360.0),
                      tx_beamwidth_v=s.tx_along, pulse_length=2.0 * s.bin_width / float(sound_speed))
    else:
        params.update(kind=s.kind.name, n_pings=1, bearing_start=0.0, bearing_step=0.0,
                      beamwidth_h=s.rx_across, beamwidth_v=s.tx_along)
    return HeadSetup(s, params, mount)


def sonar_xml(name, sensor_id="echosounder", **overrides) -> str:
    """A ``<sensor type="sonar">`` element for preset ``name`` (`configure`'s overrides)."""
    from mitsonar.sim.sensor_xml import sensor_xml

    head = name if isinstance(name, HeadSetup) else configure(name, **overrides)
    return sensor_xml(head.params, head.mount.ravel(), sensor_id)
