"""Labels of a scan: which shape returned each bin's energy, and each row's first return.

The labels come from the render itself, not from a second trace: `labelling_integrator` is a
``sonar_tof`` integrator whose histogram pass (the pass of ``plugins/integrators/sonar_tof.py``, same lanes,
same path function `SonarIntegrator.sample`) puts each echo's energy into a bin of
``(row, range bin, shape)``; ``record(k, range, energy, valid, hit)`` gets the echo's surface
interaction and ``hit.shape`` names the shape. The histogram `render_scan` sees is the sum over
shapes, so the intensity and the labels come from the same paths.

Shape ids: shape ``j`` of ``scene.shapes()`` (the scene's order, fixed by its XML) has label
``j + 1``; 0 is "no echo". In the kernel a shape pointer is turned into its index by a table
indexed by the pointer's registry id (``dr.reinterpret_array(UInt32, ShapePtr)``, the same
number ``scene.shapes_dr()`` holds for shape ``j``). Load the scene with ``optimize=False``:
Mitsuba otherwise merges the shapes that share a BSDF into one mesh, and their labels with them.
"""
from __future__ import annotations

import numpy as np

#: Echo slots (lanes x bounces) of one labelling pass: 12 bytes each, so about 100 MB.
LANE_SLOTS = 1 << 23


def shape_names(scene) -> list:
    """The names of ``scene.shapes()`` in order: each shape's id, or ``shape_<j>`` when it has none."""
    return [s.id() or f"shape_{j}" for j, s in enumerate(scene.shapes())]


def labelling_integrator(max_depth=5, sampling="sobol"):
    """A ``sonar_tof`` integrator (of the active variant) that also keeps, after each
    ``render_histogram`` (or ``render_histogram_device``), ``last_energy``: float64 ``(n_rows, n_bins, n_shapes)``, the mean echo
    energy per bin from each shape (its sum over shapes is the histogram it returns)."""
    import drjit as dr
    import mitsuba as mi

    from mitsonar.sim.variant import ensure_variant

    ensure_variant()
    from mitsonar.plugins.integrators.sonar_tof import SonarTOFIntegrator as base

    class LabellingIntegrator(base):
        name = "sonar_tof"

        def render_histogram_device(self, scene, sensor=0, seed=0, spp=4096, pose=None, max_depth=None,
                                    progress=None):
            # the sums per shape are NumPy's (`_label_pass`): their sum over shapes is uploaded
            # (``render_histogram`` brings it back, `render_frame` keeps it)
            setup = self.setup(scene, sensor, pose, max_depth)
            shapes = scene.shapes_dr()
            n_shapes = max(1, len(scene.shapes()))
            registry = dr.reinterpret_array(mi.UInt32, shapes).numpy() if len(scene.shapes()) else np.zeros(1, np.uint32)
            table = np.zeros(int(registry.max()) + 1, np.uint32)
            table[registry] = np.arange(len(registry), dtype=np.uint32)
            table = mi.UInt32(table)
            n_rows, n_bins = setup.sensor.n_pings, setup.sensor.n_bins
            total = self.accumulate(spp, LANE_SLOTS // (n_rows * setup.depth),
                                    lambda start, count: self._label_pass(setup, seed, start, count, table, n_shapes),
                                    progress)
            energy = total.reshape(n_rows, n_bins, n_shapes)
            self.last_energy = energy
            from mitsonar.plugins.integrators.paths.exact_sum import with_float32

            return with_float32(energy.sum(axis=2).ravel())

        def _label_pass(self, setup, seed, start, count, table, n_shapes):
            # No atomics: every echo goes to its own slot (lane, bounce), and the slots are summed
            # into the bins in slot order by numpy. Float sums depend on their order, and atomic
            # adds take the order the threads happen to run in; this one is fixed, so the same
            # sample comes out bit for bit the same with 1 thread or 16.
            n_rows, n_bins = setup.sensor.n_pings, setup.sensor.n_bins
            ping, samples = self.lanes(n_rows, seed, start, count)
            n_cells = n_rows * n_bins * n_shapes
            n_slots = n_rows * count * setup.depth
            where = dr.full(mi.UInt32, n_cells, n_slots)   # n_cells: an empty slot
            amount = dr.zeros(mi.Float, n_slots)
            bins = setup.bins
            n_o, depth_o = dr.opaque(mi.UInt32, n_shapes), setup.depth_o
            lane = dr.arange(mi.UInt32, n_rows * count)

            def record(depth_k, rng, energy, valid, hit):
                b, valid = bins.index(rng, valid)
                shape = dr.gather(mi.UInt32, table, dr.reinterpret_array(mi.UInt32, hit.shape), valid)
                slot = lane * depth_o + depth_k
                dr.scatter(where, bins.flat(ping, b) * n_o + shape, slot, valid)
                dr.scatter(amount, energy, slot, valid)

            self.sample(setup, ping, samples, record)
            # Subnormal echoes (< 1.2e-38) are dropped: the threads of Dr.Jit's pool flush them to
            # zero and the calling thread may not, so they would differ with the thread count.
            energy = amount.numpy().astype(np.float64)
            energy[np.abs(energy) < np.finfo(np.float32).tiny] = 0.0
            return np.bincount(where.numpy(), weights=energy, minlength=n_cells + 1)[:n_cells]

    props = mi.Properties("sonar_tof")
    props["max_depth"] = int(max_depth)
    props["sampling"] = str(sampling)
    return LabellingIntegrator(props)


def segmentation(energy) -> np.ndarray:
    """int32 ``(n_rows, n_bins)``: per bin the label (shape index + 1) of the shape that returned
    the most energy, 0 where no echo landed (ties go to the lower index)."""
    energy = np.asarray(energy)
    seg = np.argmax(energy, axis=2).astype(np.int32) + 1
    seg[~(energy.sum(axis=2) > 0)] = 0
    return seg


def first_return(intensity, ranges, threshold_db=-20.0) -> np.ndarray:
    """float32 ``(n_rows,)``: per row the centre range of the first bin whose intensity is within
    ``threshold_db`` (<= 0) of the row's peak (a range image of the nearest surface the beam sees);
    NaN for a row with no echo."""
    intensity = np.asarray(intensity, np.float64)
    peak = intensity.max(axis=1, keepdims=True)
    above = (intensity > 0) & (intensity >= peak * 10.0 ** (threshold_db / 10.0))
    first = np.argmax(above, axis=1)
    out = np.asarray(ranges, np.float64)[first].astype(np.float32)
    out[~above.any(axis=1)] = np.nan
    return out
