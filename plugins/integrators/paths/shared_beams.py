"""Transmit paths shared by the receive beams of one multibeam frame (``sonar_tof`` ``share_beams``).

A multibeam frame's rows share one head pose and one transmit fan ``B_tx`` fixed in the head
frame; row ``k`` is a receive beam ``B_rx`` steered to bearing ``b_k`` about the head's +y. The
per-row estimator (`common.SonarIntegrator.sample` with ``setup.connect``) traces ``spp`` paths
per row from row k's receive beam and weights the connection by ``B_tx``. Here the frame's
``n_rows * spp`` paths are emitted from the transmit fan instead (``B_tx / pdf_tx``), and the echo
of every bounce is scored into every receive beam whose pattern reaches the connection
direction, with weight ``B_rx(d in row k's frame)``:

    E_k = throughput_tx * f * B_rx,k(d) / r^2 * 10^(-absorption L / 10)

per path, averaged over the frame's ``N = n_rows * spp`` paths (each adds ``E_k / n_rows`` and the
histogram is divided by ``spp``): ``spp`` keeps its meaning, paths per row on average, and a
frame traces as many paths as with the per-row estimator. The path density is the fan's and
the receive gain is evaluated exactly, so each row's estimate has the expectation of the
per-row estimator's (the two-way gain ``B_tx B_rx,k`` and the path lengths are the same by
reciprocity; the acoustic BSDF is symmetric); what changes is the variance: every path now
counts for every beam it reaches (a few either side of its nearest), and the transmit paths of
a frame are one Owen-scrambled Sobol sequence over the whole fan.

Row k's frame is the head frame turned by ``b_k`` about +y, so a head-frame direction of azimuth
``az = atan2(x, z)`` and elevation ``el = asin(y)`` has azimuth ``az - b_k`` (wrapped to
``(-pi, pi]``) and the same elevation in row k's frame. The beams scored are those with
``|az - b_k| <= W``, found from the nearest one: ``W`` is the receive pattern's azimuth support
(``BeamPattern.support``) except for a gaussian, where it is 2 beam widths (``Gaussian.SHARE_WINDOW``
in ``plugins/sensors/beam.py``) (beyond, ``B < 2^-16``
and the pattern's mass is below 1e-5 of the beam's: the truncation is far below any Monte-Carlo
error at reachable spp). A ``sinc`` receive pattern (side lobes over the whole half-space)
would be scored into every row: it is refused with ``share_beams="true"``, as are echoes reaching
more than `MAX_BEAMS` beams, and left to the per-row paths when ``share_beams`` is unset (`can_share`).
"""
from __future__ import annotations

import math
from types import SimpleNamespace

import drjit as dr
import mitsuba as mi
import numpy as np

import mitsonar.kinds as kinds
from mitsonar.plugins.jit_arrays import upload
from mitsonar.plugins.sensors.sonar import PingFrames

from .range_bins import RangeBins

# Beams scored per echo at most: the window either side of the nearest (2 m + 1 beams), or every
# row of a frame narrower than that.
MAX_BEAMS = 65
# Float64 atomics straight to memory: the echoes of one SIMD packet rarely share a bin, so the
# packet-local pre-reduction of the default mode only costs (one A/B on a loaded machine: a
# quay-wall frame at spp 256 took 0.10 s against 0.14-0.16 s with ReduceMode.Auto).
SCATTER_MODE = dr.ReduceMode.Direct
# Russian roulette for faint beams: a beam whose gain g is below this is scored with probability
# g / ROULETTE_GAIN at weight ROULETTE_GAIN (expectation g, unbiased), which spares most of the
# float64 scatters of a gaussian window's tails (0 turns it off).
ROULETTE_GAIN = 0.01


def window(sensor):
    """(W radians, m beams either side of the nearest) of ``sensor``'s receive beams, or a
    ValueError naming ``share_beams`` when sharing cannot apply to this head."""
    beam = sensor.beam
    if not sensor.sonar_kind.share_beams:   # receive beams in one fan (a volumetric grid's are not)
        raise ValueError(f"sonar_tof 'share_beams': only for a sensor of kind {kinds.which('share_beams')} "
                         f"(kind is {sensor.kind!r})")
    w = beam.shape.share_window(beam)
    bearings = np.radians(sensor.bearings_deg())
    # the narrowest spacing of the rows (a head's own table may be uneven: more beams per degree
    # near its boresight), so that the window either side of the nearest covers W everywhere
    step = abs(math.radians(sensor.bearing_step))
    if len(bearings) > 1 and not np.allclose(np.abs(np.diff(bearings)), step, rtol=0.0, atol=1e-12):
        step = float(np.min(np.abs(np.diff(bearings))))
    swath = float(bearings.max() - bearings.min())
    if swath + 2 * w >= 2 * math.pi:
        raise ValueError("sonar_tof 'share_beams': the receive beams' windows overlap across a full turn "
                         f"(swath {math.degrees(swath):g} deg + 2 x {math.degrees(w):g} deg); use share_beams false")
    m = sensor.n_pings if step == 0 else int(math.ceil(w / step))
    if min(2 * m + 1, sensor.n_pings) > MAX_BEAMS:
        raise ValueError(f"sonar_tof 'share_beams': each echo would reach {2 * m + 1} receive beams (beam "
                         f"{beam.beamwidth_h:g} deg, step {math.degrees(step):g} deg), more than {MAX_BEAMS}; "
                         "use share_beams false")
    return w, m


def can_share(sensor):
    """True when ``sensor``'s frames can share paths (`window` accepts it): the default of
    ``sonar_tof``'s ``share_beams``, which falls back to per-row paths otherwise."""
    try:
        window(sensor)
    except ValueError:
        return False
    return True


class _Gate:
    """The connection 'pattern' of a shared path: 1 where some receive beam can hear the direction
    (azimuth within the swath widened by W, elevation within the receive support), else 0, so that
    no visibility ray is cast for an echo no beam receives."""

    def __init__(self, lo, hi, el_lo, el_hi):
        self.lo, self.hi = dr.opaque(mi.Float, lo), dr.opaque(mi.Float, hi)
        self.el_lo, self.el_hi = dr.opaque(mi.Float, el_lo), dr.opaque(mi.Float, el_hi)

    def eval_dir(self, d):
        az, el = dr.atan2(d.x, d.z), dr.safe_asin(d.y)
        centre = 0.5 * (self.lo + self.hi)
        az = centre + _wrap(az - centre)
        inside = (az >= self.lo) & (az <= self.hi) & (el >= self.el_lo) & (el <= self.el_hi)
        return dr.select(inside, mi.Float(1.0), mi.Float(0.0))


def _wrap(a):
    """Angles to (-pi, pi]."""
    return a - (2 * math.pi) * dr.round(a * (0.5 / math.pi))


class SharedFrame:
    """The `common.PathSetup` of a frame's shared paths, and the scoring of their echoes.

    ``path_setup`` is what `SonarIntegrator.sample` traces with: the transmit fan as the emitted
    beam, the head frame for every lane, a gate (`_Gate`) as the connection. `score` adds one
    bounce's echoes into the rows that hear them.
    """

    def __init__(self, setup, pose=None):
        sensor = setup.sensor
        self.sensor = sensor
        self.w, self.m = window(sensor)
        head = sensor.head_pose(pose)
        head = head[0] if head.ndim == 3 else head
        lo, hi, el_lo, el_hi = sensor.beam.support()
        bearings = np.radians(sensor.bearings_deg())
        gate = _Gate(float(bearings.min()) - self.w, float(bearings.max()) + self.w, el_lo, el_hi)
        frames = PingFrames(head[None])
        self.path_setup = SimpleNamespace(scene=setup.scene, sensor=SimpleNamespace(beam=sensor.transmit),
                                          frames=frames, connect=(frames, gate), depth=setup.depth,
                                          depth_o=setup.depth_o, absorption=setup.absorption, bins=setup.bins,
                                          guide=setup.guide, refraction=getattr(setup, "refraction", None))
        self.axes = [_opaque(mi.Vector3f, head[:3, c]) for c in range(3)]
        self.origin = _opaque(mi.Point3f, head[:3, 3])
        self.start = dr.opaque(mi.Float, bearings[0])
        self.step = float(math.radians(sensor.bearing_step))
        # An uneven table of bearings (the head's own, `sensors.sonar` ``bearings``): the nearest
        # row is found by a binary search and row k's bearing read from the table; an even one
        # scores as ``start + k step`` does.
        even = np.allclose(np.diff(bearings), self.step, rtol=0.0, atol=1e-12) if len(bearings) > 1 else True
        self.table = None if even else upload(mi.Float, bearings, np.float32)
        self.inv_step = dr.opaque(mi.Float, 0.0 if self.step == 0 else 1.0 / self.step)
        self.step_o = dr.opaque(mi.Float, self.step)
        self.w_o = dr.opaque(mi.Float, self.w)
        self.n_rows = sensor.n_pings
        self.inv_rows = dr.opaque(mi.Float, 1.0 / self.n_rows)
        self.last_row = dr.opaque(mi.Float, self.n_rows - 1)
        self.centre = dr.opaque(mi.Float, bearings[0] + 0.5 * (self.n_rows - 1) * self.step)
        self.bins = RangeBins(sensor)
        # read here, so that a frozen pass's key (`frozen_pass.Context`) holds them
        self.roulette, self.scatter_mode = float(ROULETTE_GAIN), SCATTER_MODE.name

    def score(self, hist, rng, energy, valid, hit, u=None, direction=None):
        """Add the echoes of one bounce (``energy`` without the receive gain) into ``hist`` (flat
        n_rows x n_bins, an `exact_sum.ExactBins`) for every row within the window of the echo's direction.
        ``u``: a uniform number per echo for the roulette of faint beams (`ROULETTE_GAIN`); the
        beams of one echo share it (each beam's expectation is its gain either way).
        ``direction``: where the echo arrives from at the head (world, unit; a refracted path's
        eigenray, `refraction.Refraction.arrival`); default straight from the head to ``hit.p``."""
        beam = self.sensor.beam
        d = dr.normalize(hit.p - self.origin) if direction is None else direction
        x, y, z = (dr.dot(d, a) for a in self.axes)
        az, el = dr.atan2(x, z), dr.safe_asin(y)
        az = self.centre + _wrap(az - self.centre)
        if self.table is None:
            nearest = dr.round((az - self.start) * self.inv_step)
        else:
            nearest = self._nearest(az)
        b, valid = self.bins.index(rng, valid)
        energy = energy * self.inv_rows
        # The window either side of the nearest beam, or every row when that is fewer.
        every = 2 * self.m + 1 >= self.n_rows
        for o in (range(self.n_rows) if every else range(-self.m, self.m + 1)):
            k = mi.Float(o) if every else nearest + o
            off = az - self._bearing(k)
            use = valid & (k >= 0) & (k <= self.last_row) & (dr.abs(off) <= self.w_o)
            gain = beam.eval(off, el)
            use &= gain > 0
            if u is not None and self.roulette > 0:
                faint = gain < self.roulette
                use &= ~faint | (u * self.roulette < gain)
                gain = dr.select(faint, self.roulette, gain)
            row = mi.UInt32(dr.maximum(k, 0.0))
            _add_where(hist, energy * gain, self.bins.flat(row, b), use, getattr(dr.ReduceMode, self.scatter_mode))


    def _bearing(self, k):
        """Row ``k``'s bearing (rad; k a Float, clamped to the rows for the table's gather)."""
        if self.table is None:
            return self.start + k * self.step_o
        return dr.gather(mi.Float, self.table, mi.UInt32(dr.clip(k, 0.0, self.last_row)))

    def _nearest(self, az):
        """The row of the table whose bearing is nearest ``az`` (a Float row index)."""
        last = self.n_rows - 1
        hi = dr.binary_search(0, last, lambda j: dr.gather(mi.Float, self.table, j) < az)
        lo = mi.UInt32(dr.maximum(mi.Int32(hi) - 1, 0))
        below = dr.abs(az - dr.gather(mi.Float, self.table, lo)) < dr.abs(dr.gather(mi.Float, self.table, hi) - az)
        return mi.Float(dr.select(below, lo, hi))


def _add_where(hist, values, index, use, mode):
    """``hist.add(values, index, use)`` inside a symbolic ``if use``: the same adds, but a SIMD
    packet in which no lane hears this beam skips the add's scatters. An LLVM scatter-add visits
    every lane of its packet, active or not, and most echoes reach only the beams next to the
    nearest: with the 9 beams of the 512-beam quay frame, scatters with no active lane were 3 of
    its 23 ms at spp 256, and this ``if`` took the frame from 22.9-25.6 ms to 21.8-22.5 ms (three
    runs each, alternating). The sums are order-independent (`exact_sum`): the same bits."""

    def add(use, values, index):
        hist.add(values, index, use, mode=mode)

    def skip(use, values, index):
        pass

    dr.if_stmt((use, values, index), use, add, skip, mode="symbolic")


def _opaque(cls, values):
    """A 3-vector of ``cls`` made opaque (a new pose reuses the compiled kernels)."""
    v = cls(*(float(t) for t in values))
    dr.make_opaque(v)
    return v


def same_pose(sensor, pose):
    """True when every row of a render has one head pose (``pose`` None or one 4x4, or per-row
    poses that are all equal): the condition for sharing paths between rows."""
    if pose is None:
        return True
    m = np.asarray(pose, dtype=np.float64)
    return m.ndim == 2 or bool(np.all(m == m[:1]))
