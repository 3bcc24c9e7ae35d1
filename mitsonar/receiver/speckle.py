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
with ``w_m ~ N(0, 8 ln2 I)`` and ``phi_m ~ U(0, 2 pi)`` from the scene's ``speckle_seed``
(``M = 128``: by the central limit theorem ``g`` is then complex Gaussian, ``|g|^2`` exponential
with mean 1, to well within the tests' bounds). The phase splits into a row part (``b``, ``o``)
and a bin part (``r``), so the whole scan's field is one complex matrix product
``(n_rows x M) (M x n_bins)``: milliseconds. The speckle seed fixes the scatterers; the
electronics seed never touches them.

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

import contextlib
import math

import numpy as np

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
_blas = None   # threadpoolctl's BLAS controllers, found on first use (`one_blas_thread`)


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
        ``g`` with ``E|g|^2 = 1``: the amplitude factor of each bin's echo; read-only, shared with
        later calls with the same arguments (a still head's frames: `CACHE_SIZE`).
    """
    poses = np.asarray(poses, dtype=np.float64)
    ranges = np.asarray(ranges, dtype=np.float64)
    for name, value in (("beamwidth_h", beamwidth_h), ("aperture_h", aperture_h), ("resolution", resolution)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"speckle '{name}': {value!r} is not allowed (a positive number)")
    key = (poses.shape, poses.tobytes(), ranges.shape, ranges.tobytes(), int(seed), float(beamwidth_h),
           float(aperture_h), float(resolution), int(n_features))
    hit = _cache.get(key) if CACHE_SIZE > 0 else None
    if hit is not None:
        return hit
    field = _field(poses, ranges, seed, beamwidth_h, aperture_h, resolution, n_features)
    if CACHE_SIZE > 0:
        field.setflags(write=False)   # shared between scans: nobody may change it in place
        if len(_cache) >= CACHE_SIZE:
            _cache.pop(next(iter(_cache)))
        _cache[key] = field
    return field


def _tables(seed, ranges, resolution, n_features):
    """The field's features ``w`` (7, M), phases ``phi`` (M,) and bin factors ``exp(i r w_7 / L)``
    (n_bins, M) for a seed, bin ranges and resolution: they do not depend on the pose, so a
    moving head's pings share them (kept per arguments, `CACHE_SIZE`; 0: computed every call).
    The same numbers either way: for a one-row ping the bin factors were most of the field's cost
    (76 800 complex exponentials for 600 bins)."""
    key = (int(seed), ranges.shape, ranges.tobytes(), float(resolution), int(n_features))
    hit = _tables_cache.get(key) if CACHE_SIZE > 0 else None
    if hit is not None:
        return hit
    rng = np.random.default_rng([0x5BEC, int(seed)])
    w = rng.normal(0.0, math.sqrt(FREQUENCY_VARIANCE), size=(7, n_features))
    phi = rng.uniform(0.0, 2.0 * math.pi, size=n_features)
    bin_phase = np.outer(ranges / resolution, w[6])                 # (n_bins, M)
    tables = (w, phi, np.exp(1j * bin_phase))
    if CACHE_SIZE > 0:
        for a in tables:
            a.setflags(write=False)
        if len(_tables_cache) >= CACHE_SIZE:
            _tables_cache.pop(next(iter(_tables_cache)))
        _tables_cache[key] = tables
    return tables


def one_blas_thread():
    """A context in which NumPy's BLAS runs on the calling thread only (``threadpoolctl``).

    The field's products are small (a one-row ping: 1 x 128 x 600); handing them to OpenBLAS's
    threads wakes threads that then spin waiting for more work, on the cores the renderer's
    kernels and Python need: measured in benchmarks/frame_profile.py ``--fixed-only`` (harbour
    live ping), the speckle stage took 11 ms instead of 0.8 ms and the next ping's kernel replay
    7 ms instead of 2.6 ms. The products' numbers do not change (OpenBLAS splits a product by
    output blocks, each summed by one thread in the same order: tests/test_frame_overhead.py).
    """
    global _blas
    if _blas is None:
        try:
            from threadpoolctl import ThreadpoolController

            _blas = [lib for lib in ThreadpoolController().lib_controllers if lib.user_api == "blas"]
        except Exception:   # noqa: BLE001 - no control over the BLAS: run it as it comes
            _blas = []
    return _held_to_one(_blas) if _blas else contextlib.nullcontext()


@contextlib.contextmanager
def _held_to_one(libs):
    """Each BLAS library of ``libs`` (threadpoolctl's controllers) on one thread for the block,
    its count given back after (a few microseconds: ``threadpool_limits`` would look the
    libraries up again on every call, 1 ms)."""
    before = [lib.get_num_threads() for lib in libs]
    for lib in libs:
        lib.set_num_threads(1)
    try:
        yield
    finally:
        for lib, n in zip(libs, before):
            lib.set_num_threads(n)


def _field(poses, ranges, seed, beamwidth_h, aperture_h, resolution, n_features):
    """`cell_speckle`'s field, computed (checked arguments)."""
    w, phi, bin_factor = _tables(seed, ranges, resolution, n_features)
    row = np.concatenate([poses[:, :3, 2] / math.radians(beamwidth_h), poses[:, :3, 3] / aperture_h], axis=1)
    with one_blas_thread():
        row_phase = row @ w[:6] + phi                                   # (n_rows, M)
        return (np.exp(1j * row_phase) @ bin_factor.T) / math.sqrt(n_features)
