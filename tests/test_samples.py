"""The primary samples' Sobol points: the second dimension from the superset-sum transform is the
direction-number definition (Joe and Kuo's second dimension: ``v_0 = 2^31``, ``v_{k+1} = v_k ^
(v_k >> 1)``), and the scrambled points are the two-dimensional net they should be."""
import numpy as np


def direction_numbers_dim2(index):
    """The definition, in NumPy: the XOR of ``v_k`` over the set bits ``k`` of each index."""
    out = np.zeros(index.shape, np.uint32)
    v = 0x80000000
    for k in range(32):
        out ^= np.where((index >> np.uint32(k)) & np.uint32(1) != 0, np.uint32(v), np.uint32(0))
        v ^= v >> 1
    return out


def test_sobol_dimension_two_is_the_direction_number_definition(mitsonar_mod):
    """Both maps are linear over GF(2): equal on the 32 one-bit indices means equal everywhere;
    checked there, on the first 2^16 indices and on random ones, and the first points against
    the printed sequence (0, 1/2, 3/4, 1/4, 5/8, 1/8, 3/8, 7/8)."""
    import mitsuba as mi

    from mitsonar.plugins.integrators.paths import samples

    rng = np.random.default_rng(5)
    index = np.concatenate([np.uint32(1) << np.arange(32, dtype=np.uint32), np.arange(1 << 16, dtype=np.uint32),
                            rng.integers(0, 2 ** 32, 1 << 16, dtype=np.uint64).astype(np.uint32)])
    got = samples._reverse_bits(samples._sobol_dim2_reversed(mi.UInt32(index))).numpy()
    np.testing.assert_array_equal(got, direction_numbers_dim2(index))
    first = got[32:40] / 2.0 ** 32
    np.testing.assert_array_equal(first, [0, 0.5, 0.75, 0.25, 0.625, 0.125, 0.375, 0.875])


def test_scrambled_sobol_points_of_a_row_are_a_net_and_differ_by_seed(mitsonar_mod):
    """The first 2^8 scrambled points of a row put exactly one point in each of the 2^8 boxes of
    every elementary shape (2^a x 2^(8-a) cells: a (0, 8, 2)-net, which Owen scrambling keeps),
    and the same index under another seed is another point."""
    import drjit as dr
    import mitsuba as mi

    from mitsonar.plugins.integrators.paths import samples

    n = 256
    pts = []
    for seed in (3, 4):
        s = samples.SobolSamples(mi.UInt32(seed), dr.zeros(mi.UInt32, n), dr.arange(mi.UInt32, n))
        p = s.get2(0)
        pts.append(np.stack([p.x.numpy(), p.y.numpy()], axis=1))
    for xy in pts:
        assert np.all((xy >= 0) & (xy < 1))
        for a in range(9):
            cells = np.floor(xy[:, 0] * 2 ** a).astype(int) * 2 ** (8 - a) + np.floor(xy[:, 1] * 2 ** (8 - a)).astype(int)
            assert np.array_equal(np.sort(cells), np.arange(n)), a
    assert not np.array_equal(pts[0], pts[1])
