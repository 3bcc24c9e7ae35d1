"""Speckle that follows the scene: a bin's speckle belongs to the resolution cell it sees (where in
the world its echo comes from), not to the render, so it is the same ping after ping while the head
holds still and changes at the physical rate when it moves or turns.

Physics. A bin's echo is the coherent sum of the returns of the many scatterers inside its
resolution cell, ``F = sum_s a_s exp(i 2 k r_s)``; with many scatterers of random phase ``F`` is a
circular complex Gaussian (fully developed speckle: exponential intensity, Rayleigh amplitude;
Goodman 1976, *Statistical properties of laser speckle patterns*; thesis section 2.4.1). ``F``
depends only on which scatterers the cell holds and on their phases ``2 k r_s``, so in a static
scene it changes only when

* the head **turns**: the beam weights other scatterers. For a Gaussian beam of one-way -3 dB
  width ``beta`` the intensity correlation after a turn ``Delta`` is
  ``exp(-8 ln2 (Delta / beta)^2)`` (the overlap of the two-way patterns): 0.25 at half a beam
  width, 0.004 at one beam width;
* the head **moves**: the scatterers' phase differences across the cell change. By the van
  Cittert-Zernike theorem the field correlation under a sideways shift is the autocorrelation of
  the two-way aperture: the pattern is mostly gone after about half the aperture ``D``
  (Burckhardt 1978, *Speckle in ultrasound B-mode scans*; Wagner et al. 1983);
* the **range** changes by about the pulse's range resolution ``L = c tau / 2`` (or a bin, if
  wider): neighbouring bins within one pulse share scatterers, so speckle grains are a pulse long.

Model. A bin is the resolution cell of its row's beam (boresight ``b``, a unit vector in the
world), the head's position ``o`` and the bin's range ``r``, with the feature vector

    v = ( b / beta_h ,  o / D_h ,  r / L )      (7 numbers)

and its complex speckle amplitude is a stationary complex Gaussian random field of ``v`` with the
squared-exponential covariance ``E[g(v) g*(v')] = exp(-4 ln2 |v - v'|^2)``, so that the intensity
correlation ``|rho|^2 = exp(-8 ln2 |v - v'|^2)`` is the Gaussian-beam law above along every
direction of ``v``: a turn of one beam width or a shift of one aperture leaves 0.004, half of
either 0.25; neighbouring bins 2.4 cm apart under a 7.5 cm pulse keep 0.57. The field is drawn by
random Fourier features (Rahimi and Recht 2007): ``g(v) = M^-1/2 sum_m exp(i (w_m . v + phi_m))``
with ``w_m ~ N(0, 8 ln2 I)`` and ``phi_m ~ U(0, 2 pi)`` drawn from the scene's ``speckle_seed``
by the counter-based generator of `mitsonar.receiver.devicechain` (``M = 128``: by the central
limit theorem ``g`` is then complex Gaussian, ``|g|^2`` exponential with mean 1, to well within
the tests' bounds). The phase splits into a row part (``b``, ``o``) and a bin part (``r``), so
the whole scan's field is a complex matrix product ``(n_rows x M) (M x n_bins)``, computed as
Dr.Jit kernels of the active variant (each bin sums its M products in a fixed order: the same
numbers for any thread count; on the GPU for ``cuda``). The speckle seed fixes the scatterers;
the electronics seed never touches them. Before version 0.3 the features were NumPy's draws and
the product NumPy's: the same law, other numbers.

Why cells and not echo points: keying the field on each bin's mean echo point (measured, box
scene, spp 1024) made the pattern depend on the path seed (byte correlation 0.40 between two path
seeds at one pose): a bin holding multipath echoes has a last bounce point that wanders from seed
to seed. A cell is fixed by the pose and the range, so a still head sees the same pattern
whatever the path seed.

Approximations, stated: the scene is static (an object moving in front of a still head keeps the
pattern of the cells it passes through); turns about either axis decorrelate over the narrow beam
width ``beta_h`` (tilting a mechanical head decorrelates faster than its wide ``beta_v`` would
give; rolling about the boresight not at all); the head's position enters in all three directions
(a shift along the line of sight decorrelates over about half an aperture instead of about a pulse
length: at the Micron's 3.6 cm aperture and 7.5 cm pulse, within a factor of two).
"""
from __future__ import annotations

import math

import numpy as np

import mitsonar.receiver.devicechain as _dev

#: Random Fourier features of the field (see the module docstring).
N_FEATURES = 128
#: Variance of the features' frequencies: intensity correlation exp(-8 ln2 |dv|^2).
FREQUENCY_VARIANCE = 8.0 * math.log(2.0)
#: Fields kept per process, keyed by every input (`cell_speckle`): a still head's frames share one
#: field, which is the same numbers whether computed or looked up (0 turns the cache off).
CACHE_SIZE = 4
_cache: dict = {}
#: The pose-free tables of the field (`_tables`), keyed by seed, ranges, resolution and features.
_tables_cache: dict = {}


class Field:
    """A scene's complex speckle amplitude per bin on the device: ``re``, ``im`` (``mi.Float64``,
    ``n_rows x n_bins`` values, row-major) and ``shape``. `numpy` gives it as complex128."""

    __slots__ = ("re", "im", "shape", "_host")

    def __init__(self, re, im, shape):
        self.re, self.im, self.shape, self._host = re, im, tuple(shape), None

    def numpy(self) -> np.ndarray:
        """complex128 ``shape``, read-only (computed once per field)."""
        if self._host is None:
            g = np.empty(self.shape, dtype=np.complex128)
            g.real = self.re.numpy().reshape(self.shape)
            g.imag = self.im.numpy().reshape(self.shape)
            g.setflags(write=False)
            self._host = g
        return self._host


def _check(beamwidth_h, aperture_h, resolution):
    for name, value in (("beamwidth_h", beamwidth_h), ("aperture_h", aperture_h), ("resolution", resolution)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"speckle '{name}': {value!r} is not allowed (a positive number)")


def field(poses, ranges, *, seed: int, beamwidth_h: float, aperture_h: float, resolution: float,
          n_features: int = N_FEATURES) -> Field:
    """The scene's speckle of every bin of a scan as a device `Field` (`cell_speckle`'s
    arguments); shared with later calls with the same arguments (a still head's frames:
    `CACHE_SIZE`)."""
    poses = np.asarray(poses, dtype=np.float64)
    ranges = np.asarray(ranges, dtype=np.float64)
    _check(beamwidth_h, aperture_h, resolution)
    key = (_dev.variant(), poses.shape, poses.tobytes(), ranges.shape, ranges.tobytes(), int(seed),
           float(beamwidth_h), float(aperture_h), float(resolution), int(n_features))
    hit = _cache.get(key) if CACHE_SIZE > 0 else None
    if hit is not None:
        return hit
    out = _field(poses, ranges, seed, beamwidth_h, aperture_h, resolution, n_features)
    if CACHE_SIZE > 0:
        if len(_cache) >= CACHE_SIZE:
            _cache.pop(next(iter(_cache)))
        _cache[key] = out
    return out


def cell_speckle(poses, ranges, *, seed: int, beamwidth_h: float, aperture_h: float, resolution: float,
                 n_features: int = N_FEATURES) -> np.ndarray:
    """Complex speckle amplitude (complex128, n_rows x n_bins) of every bin of a scan.

    Parameters
    ----------
    poses : (n_rows, 4, 4)
        Each row's beam-frame pose in the world: ``[:3, 2]`` its boresight, ``[:3, 3]`` the head.
    ranges : (n_bins,)
        Bin-centre ranges (m).
    seed : int
        The scene's speckle seed (which scatterers the surfaces hold).
    beamwidth_h : float
        deg, the narrow one-way -3 dB beam width: turns decorrelate over it.
    aperture_h : float
        m, the aperture across the narrow beam: shifts decorrelate over half of it.
    resolution : float
        m, the range resolution (the pulse's ``c tau / 2``, at least a bin).
    n_features : int
        Random Fourier features (module docstring).

    Returns
    -------
    ndarray complex128
        ``g`` with ``E|g|^2 = 1``: the amplitude factor of each bin's echo, the host copy of
        `field` (read-only, shared with later calls with the same arguments).
    """
    return field(poses, ranges, seed=seed, beamwidth_h=beamwidth_h, aperture_h=aperture_h,
                 resolution=resolution, n_features=n_features).numpy()


def _tables(seed, ranges, resolution, n_features):
    """The field's features ``w`` (7 x M, row-major) and phases ``phi`` (M) as ``mi.Float64``,
    drawn by `devicechain.normals` from the seed (stream `devicechain.STREAM_FEATURES`), and the
    bin factors ``exp(i r w_7 / L)`` (``re``, ``im`` as ``mi.Float32``, M x n_bins, feature-major) for a seed, bin
    ranges and resolution: they do not depend on the pose, so a moving head's pings share them
    (kept per arguments, `CACHE_SIZE`; 0: computed every call)."""
    import drjit as dr
    import mitsuba as mi

    key = (_dev.variant(), int(seed), ranges.shape, ranges.tobytes(), float(resolution), int(n_features))
    hit = _tables_cache.get(key) if CACHE_SIZE > 0 else None
    if hit is not None:
        return hit
    m = int(n_features)
    with dr.suspend_grad():
        # eight normals and a uniform per feature: w[d, m] (d < 7), phi[m]
        k = dr.arange(mi.UInt32, m)
        n0, n1, n2, n3 = _dev.normals(seed, _dev.STREAM_FEATURES, k, mi.UInt32(0))
        n4, n5, n6, _ = _dev.normals(seed, _dev.STREAM_FEATURES, k, mi.UInt32(1))
        u = _dev.uniforms(seed, _dev.STREAM_FEATURES, k, mi.UInt32(2))
        sd = math.sqrt(FREQUENCY_VARIANCE)
        w = [n * sd for n in (n0, n1, n2, n3, n4, n5, n6)]
        phi = u * (2.0 * math.pi)
        dr.eval(w, phi)
        n_bins = ranges.size
        lane = dr.arange(mi.UInt32, m * n_bins)
        nb = dr.opaque(mi.UInt32, n_bins)
        f = lane // nb
        b = lane - f * nb
        r = dr.gather(mi.Float64, mi.Float64(np.ascontiguousarray(ranges)), b)
        s, c = dr.sincos(_reduced(r * (1.0 / float(resolution)) * dr.gather(mi.Float64, w[6], f)))
        c, s = mi.Float32(c), mi.Float32(s)
        dr.eval(c, s)
    tables = (w, phi, c, s)
    if CACHE_SIZE > 0:
        if len(_tables_cache) >= CACHE_SIZE:
            _tables_cache.pop(next(iter(_tables_cache)))
        _tables_cache[key] = tables
    return tables


def _reduced(phase):
    """``phase`` reduced into [-pi, pi] in float64 (positions in the world make phases of
    thousands of radians: the sine and cosine stay accurate)."""
    import drjit as dr

    return phase - dr.round(phase * (0.5 / math.pi)) * (2.0 * math.pi)


def _field(poses, ranges, seed, beamwidth_h, aperture_h, resolution, n_features):
    """`field`, computed (checked arguments): the row phasors ``exp(i (w . v_row + phi))`` (one
    kernel of n_rows x M), then each bin's sum over the features in a fixed order (one kernel
    of n_rows x n_bins lanes looping over M): the same numbers for any thread count."""
    import drjit as dr
    import mitsuba as mi

    w, phi, bc, bs = _tables(seed, ranges, resolution, n_features)
    n_rows, n_bins, m = poses.shape[0], ranges.size, int(n_features)
    row = np.concatenate([poses[:, :3, 2] / math.radians(beamwidth_h), poses[:, :3, 3] / aperture_h], axis=1)
    with dr.suspend_grad():
        feats = mi.Float64(np.ascontiguousarray(row).reshape(-1))
        lane = dr.arange(mi.UInt32, n_rows * m)
        mm = dr.opaque(mi.UInt32, m)
        r = lane // mm
        f = lane - r * mm
        phase = dr.gather(mi.Float64, phi, f)
        for d in range(6):   # the row's phase, features in a fixed order
            phase = dr.fma(dr.gather(mi.Float64, feats, r * 6 + d), dr.gather(mi.Float64, w[d], f), phase)
        rs, rc = dr.sincos(_reduced(phase))
        rc32, rs32 = mi.Float32(rc), mi.Float32(rs)
        dr.eval(rc32, rs32)
        lane = dr.arange(mi.UInt32, n_rows * n_bins)
        nb = dr.opaque(mi.UInt32, n_bins)
        r = lane // nb
        b = lane - r * nb
        # float32 phasors summed in float32 (fused multiply-adds, features in order): a bin's
        # speckle is accurate to 1e-6 of its mean amplitude, twice the speed of float64 on a CPU
        def body(k, re, im):
            ar, ai = dr.gather(mi.Float32, rc32, r * mm + k), dr.gather(mi.Float32, rs32, r * mm + k)
            br, bi = dr.gather(mi.Float32, bc, b + k * nb), dr.gather(mi.Float32, bs, b + k * nb)
            return k + 1, dr.fma(ar, br, dr.fma(-ai, bi, re)), dr.fma(ar, bi, dr.fma(ai, br, im))

        zero = dr.zeros(mi.Float32, n_rows * n_bins)
        _, re, im = dr.while_loop((dr.zeros(mi.UInt32, n_rows * n_bins), zero, zero),
                                  lambda k, re, im: k < mm, body, mode="symbolic")   # one small kernel
        re, im = mi.Float64(re), mi.Float64(im)
        scale = 1.0 / math.sqrt(m)
        re, im = re * scale, im * scale
        dr.eval(re, im)
    return Field(re, im, (n_rows, n_bins))
