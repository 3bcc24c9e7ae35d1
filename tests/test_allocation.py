"""sonar_tof's allocation="adaptive" and "auto" (plugins/integrators/paths/row_allocation.py): the paths per row,
the same expectation as the uniform render, the uniform render's bytes where the split stays even,
determinism per seed, refused settings."""
import os

import numpy as np
import pytest

from conftest import SCENES


def test_allocate_is_the_square_root_rule_with_a_floor():
    """Closed forms: with no floor, the second stage's paths go in proportion to sqrt(v) after one
    each; with the floor ``mix`` every row keeps at least ``mix`` of its uniform share; no
    variance anywhere gives the uniform split; the total is exact."""
    from mitsonar.plugins.integrators.paths.row_allocation import allocate

    # 64 paths over 4 rows: one each, then 60 as sqrt(v) = 0, 1, 2, 3 (sixths)
    assert allocate([0.0, 1.0, 4.0, 9.0], 64, mix=0.0).tolist() == [1, 11, 21, 31]
    assert allocate([0.0, 1.0, 4.0, 9.0], 64, mix=1.0).tolist() == [16, 16, 16, 16]
    assert allocate([0.0, 0.0, 0.0], 30).tolist() == [10, 10, 10]
    n = allocate([0.0, 0.0, 0.0, 100.0], 4004, mix=0.25)
    # 4000 shared: 250 each from the floor, the last row also the other 3000
    assert n.tolist() == [251, 251, 251, 3251]
    # largest remainders: the total is kept whatever the rounding
    m = allocate(np.arange(7.0) ** 3, 1001)
    assert m.sum() == 1001 and (np.diff(m) >= 0).all()
    with pytest.raises(ValueError, match="cannot give each of 5 rows one"):
        allocate(np.ones(5), 4)


def test_predicted_gain_closed_form():
    """Rows of variance 1 and 9 with 1 and 3 paths (sqrt rule): uniform 2 each gives 5, these
    give 1 + 3 = 4, a gain of 1.25; equal variances with equal paths gain nothing."""
    from mitsonar.plugins.integrators.paths.row_allocation import predicted_gain

    assert predicted_gain([1.0, 9.0], np.array([1, 3])) == pytest.approx(1.25)
    assert predicted_gain([2.0, 2.0, 2.0], np.array([5, 5, 5])) == pytest.approx(1.0)
    assert predicted_gain([0.0, 0.0], np.array([5, 5])) == 1.0


def test_a_small_predicted_gain_keeps_the_uniform_split(mitsonar_mod):
    """The periscope's pings are alike (the pilot predicts 1.08), the hidden target's nearly
    (1.2-1.3): every ping keeps its ``spp`` paths. The periscope's echoes come from every
    elevation (no guide either): the render is the uniform render to the byte (the pilot is paid
    on top and only chooses: its time is all that is lost). The hidden target's boulder answers
    at a few elevations: the pilot guides them (2x predicted), and the same paths per ping are
    drawn there."""
    import mitsuba as mi

    from mitsonar.plugins.integrators.paths.row_allocation import GUIDE_MIN_GAIN, MIN_GAIN

    uniform = mi.load_dict({"type": "sonar_tof", "allocation": "uniform"})
    for name, guided in (("periscope.xml", False), ("hidden_target.xml", True)):
        scene = mitsonar_mod.load_scene(os.path.join(SCENES, name))
        tof = mi.load_dict({"type": "sonar_tof", "allocation": "adaptive"})
        h = tof.render_histogram(scene, seed=1, spp=4096)
        assert 1.0 <= tof.last_plan["predicted_gain"] < MIN_GAIN
        assert (tof.last_counts == 4096).all() and tof.last_plan["pilot"] == 256
        assert tof.last_plan["guided"] == guided
        assert guided == (tof.last_plan["guide_gain"] is not None and tof.last_plan["guide_gain"] >= GUIDE_MIN_GAIN)
        assert np.array_equal(h, uniform.render_histogram(scene, seed=1, spp=4096)) != guided


def test_guide_tables_are_the_square_root_rule_with_a_floor():
    """Closed forms: slices of second moments 0, 4, 0, 1 with a 0.2 floor get 0.05 + 0.8 x (0, 2/3, 0,
    1/3); the cumulative sums run from 0 to 1 and their differences are the probabilities; the
    second moment left is sum m2 / (n^2 p) over the even one's mean; a row without echoes is even
    and keeps its variance."""
    from mitsonar.plugins.integrators.paths.row_allocation import guide_tables

    prob, cdf, factor = guide_tables([[0.0, 4.0, 0.0, 1.0], [0.0, 0.0, 0.0, 0.0]], mix=0.2)
    want = 0.05 + 0.8 * np.array([0.0, 2.0 / 3.0, 0.0, 1.0 / 3.0])
    np.testing.assert_allclose(prob[0], want, rtol=1e-6)
    np.testing.assert_allclose(prob[1], 0.25, rtol=1e-6)
    assert cdf[0, 0] == 0.0 and cdf[0, -1] == 1.0 and np.array_equal(np.diff(cdf, axis=1), prob)
    assert factor[0] == pytest.approx((4.0 / (16 * want[1]) + 1.0 / (16 * want[3])) / 1.25, rel=1e-6)
    assert factor[0] < 1.0 and factor[1] == 1.0


def test_warp_draws_each_slice_with_its_probability(mitsonar_mod):
    """Uniform coordinates through `warp` (2 rows, 8 slices): each slice [k/8, (k+1)/8) receives
    its probability's share of them, the map is monotone and stays in [0, 1), the density it
    returns is 8 p_k on slice k, and the importance weights 1 / density average to 1 (what makes
    the guided emission unbiased)."""
    import drjit as dr
    import mitsuba as mi

    from mitsonar.plugins.integrators.paths.row_allocation import guide_tables, warp

    rng = np.random.default_rng(5)
    prob, cdf, _ = guide_tables(rng.random((2, 8)) ** 4, mix=0.3)
    m = 1 << 16
    u = (np.arange(m) + 0.5) / m
    for row in (0, 1):
        out, dens = warp(mi.Float(u.astype(np.float32)), mi.UInt32(np.full(m, row, np.uint32)),
                         mi.Float(cdf.ravel()), mi.Float(prob.ravel()), 8)
        dr.eval(out, dens)
        out, dens = out.numpy(), dens.numpy()
        assert (np.diff(out) >= 0).all() and out.min() >= 0.0 and out.max() < 1.0
        k = np.floor(out * 8).astype(int)
        np.testing.assert_allclose(np.bincount(k, minlength=8) / m, prob[row], atol=2.0 / m)
        np.testing.assert_allclose(dens, 8 * prob[row][k], rtol=1e-6)
        assert np.mean(1.0 / dens) == pytest.approx(1.0, abs=1e-4)


def test_a_guided_even_split_draws_the_same_paths_as_the_lanes_passes(mitsonar_mod):
    """The hidden target at 4096 spp: the pilot keeps the even split and guides the emitted
    elevation. Its render (the uniform render's passes, lane indices made in the kernel, the
    emission drawn by the guide) is, to the byte, the per-lane passes (`_sums`, index arrays)
    with the same guide: the same samples of every row, the same weights."""
    import mitsuba as mi

    from mitsonar.plugins.integrators.paths import row_allocation
    from mitsonar.plugins.integrators.sonar_tof import MAX_LANES_PER_PASS

    scene = mitsonar_mod.load_scene(os.path.join(SCENES, "hidden_target.xml"))
    tof = mi.load_dict({"type": "sonar_tof", "allocation": "adaptive"})
    h = tof.render_histogram(scene, seed=1, spp=4096)
    assert tof.last_plan["guided"] and (tof.last_counts == 4096).all()
    setup = tof.setup(scene, 0, None, None)
    _, counts, _, guide = row_allocation.choose(tof, setup, 1, 4096, MAX_LANES_PER_PASS)
    assert counts is None and guide is not None
    n_rows = setup.sensor.n_pings
    (total,) = row_allocation._sums(tof, setup, 1, np.full(n_rows, 4096), MAX_LANES_PER_PASS, guide=guide)
    assert np.array_equal(h, total.reshape(n_rows, -1) / 4096)


@pytest.mark.parametrize("name", ["intake.xml", "periscope.xml"])
def test_progress_is_reported_after_each_pass(mitsonar_mod, name):
    """The adaptive render in passes of 2^14 lanes reports its progress after each (paths moved on
    the intake, kept even on the periscope): rising, ending at (spp, spp)."""
    import mitsuba as mi

    from mitsonar.plugins.integrators.paths import row_allocation

    scene = mitsonar_mod.load_scene(os.path.join(SCENES, name))
    tof = mi.load_dict({"type": "sonar_tof", "allocation": "adaptive"})
    setup = tof.setup(scene, 0, None, None)
    calls = []
    row_allocation.render(tof, setup, 3, 2048, 1 << 14, lambda done, total: calls.append((done, total)))
    moved = tof.last_plan["paths_per_row_max"] > tof.last_plan["paths_per_row_min"]
    assert moved == (name == "intake.xml")
    assert len(calls) >= 3 and calls[-1] == (2048, 2048)
    assert all(b[0] >= a[0] for a, b in zip(calls, calls[1:])) and {t for _, t in calls} == {2048}


@pytest.fixture(scope="module")
def intake(mitsonar_mod):
    return mitsonar_mod.load_scene(os.path.join(SCENES, "intake.xml"))


def test_adaptive_is_deterministic_and_moves_paths_to_the_rows_with_echoes(intake):
    """Same seed, same bytes; another seed, another scan; the budget is kept (the rows' paths sum
    to spp per row, the pilot's on top); on the intake (echoes in a few pings) the noisiest row
    gets many times the paths of the quietest, which keeps a quarter of its uniform share."""
    import mitsuba as mi

    from mitsonar.plugins.integrators.paths.row_allocation import UNIFORM_MIX

    tof = mi.load_dict({"type": "sonar_tof", "allocation": "adaptive"})
    a = tof.render_histogram(intake, seed=3, spp=256)
    counts = tof.last_counts.copy()
    b = tof.render_histogram(intake, seed=3, spp=256)
    assert np.array_equal(a, b) and np.array_equal(counts, tof.last_counts)
    assert not np.array_equal(a, tof.render_histogram(intake, seed=4, spp=256))
    assert tof.last_plan["pilot"] == 16
    n_rows = intake.sensors()[0].n_pings
    assert counts.sum() == 256 * n_rows
    assert counts.min() >= int(UNIFORM_MIX * 256)
    assert counts.max() > 10 * counts.min()


def test_small_spp_is_the_uniform_render(intake):
    """Under MIN_SPP there is no pilot: every row gets spp paths, and the render is the uniform
    one to the byte (the same samples of each row, summed exactly)."""
    import mitsuba as mi

    from mitsonar.plugins.integrators.paths.row_allocation import MIN_SPP

    spp = MIN_SPP // 2
    adaptive = mi.load_dict({"type": "sonar_tof", "allocation": "adaptive"})
    uniform = mi.load_dict({"type": "sonar_tof"})
    assert np.array_equal(adaptive.render_histogram(intake, seed=9, spp=spp),
                          uniform.render_histogram(intake, seed=9, spp=spp))
    assert adaptive.last_plan["pilot"] == 0


def test_auto_allocates_large_renders_of_rows_that_share_no_paths(mitsonar_mod, intake):
    """``auto`` (the default): under AUTO_MIN_PATHS paths (rows x spp) the render is the uniform
    one to the byte; at it, the adaptive render to the byte (the intake's paths moved); a
    multibeam whose beams share the transmit paths stays uniform (shared) at any size, and
    sonar_mlt's default path tracer follows sonar_tof's."""
    import mitsuba as mi

    from mitsonar.plugins.integrators.paths.row_allocation import AUTO_MIN_PATHS

    n_rows = intake.sensors()[0].n_pings
    auto = mi.load_dict({"type": "sonar_tof"})
    assert auto.allocation == "auto"
    small = AUTO_MIN_PATHS // n_rows // 2
    uniform = mi.load_dict({"type": "sonar_tof", "allocation": "uniform"})
    assert np.array_equal(auto.render_histogram(intake, seed=5, spp=small),
                          uniform.render_histogram(intake, seed=5, spp=small))
    large = -(-AUTO_MIN_PATHS // n_rows)
    adaptive = mi.load_dict({"type": "sonar_tof", "allocation": "adaptive"})
    h = auto.render_histogram(intake, seed=5, spp=large)
    assert np.array_equal(h, adaptive.render_histogram(intake, seed=5, spp=large))
    assert auto.last_counts.max() > 4 * auto.last_counts.min()
    mlt = mi.load_dict({"type": "sonar_mlt"})
    assert np.array_equal(h, mlt.render_histogram(intake, seed=5, spp=large))

    fls = mitsonar_mod.load_scene(os.path.join(SCENES, "fls_array.xml"))
    rows = fls.sensors()[0].n_pings
    spp = -(-AUTO_MIN_PATHS // rows)
    shared = mi.load_dict({"type": "sonar_tof", "allocation": "uniform"})
    assert np.array_equal(auto.render_histogram(fls, seed=2, spp=spp), shared.render_histogram(fls, seed=2, spp=spp))


@pytest.mark.parametrize("name, guided", [("intake.xml", False), ("box.xml", True), ("hidden_target.xml", True)])
def test_adaptive_has_the_expectation_of_the_uniform_render(mitsonar_mod, name, guided, monkeypatch):
    """Welch t tests on block sums (10 ping groups x 6 range groups, and the total) of 8 renders
    each, Bonferroni-corrected so that the whole test raises a false alarm with probability 1e-3
    when both have the same mean. The pilot chooses from its own seed, so each row's mean is
    unbiased whatever it chose (paths per row, and on the box and the hidden target the guide of
    the emitted elevation, here chosen wherever it predicts any gain so that every render tests
    it: renders guided or not mixed would widen the spread the test measures against); a pilot
    counted into the estimate by its own counts would not be."""
    import mitsuba as mi
    from scipy import stats

    from mitsonar.plugins.integrators.paths import row_allocation
    from test_mlt import grouped

    monkeypatch.setattr(row_allocation, "GUIDE_MIN_GAIN", 1.0)
    scene = mitsonar_mod.load_scene(os.path.join(SCENES, name))
    uniform = mi.load_dict({"type": "sonar_tof", "allocation": "uniform"})
    adaptive = mi.load_dict({"type": "sonar_tof", "allocation": "adaptive"})
    runs, spp = 8, 4096

    def blocks(integrator, seed):
        h = integrator.render_histogram(scene, seed=seed, spp=spp)
        return np.append(grouped(h, 10, 6), h.sum())

    a = np.stack([blocks(uniform, s) for s in range(runs)])
    b, chosen = [], []
    for s in range(runs):
        b.append(blocks(adaptive, 100 + s))
        chosen.append(adaptive.last_plan["guided"])
    b = np.stack(b)
    # the guide of the emitted elevation is what the box's and hidden target's renders test too
    if guided:
        assert all(chosen), chosen
    keep = (a.mean(0) > 1e-3 * a.mean(0).max()) & (a.std(0) > 0) & (b.std(0) > 0)
    assert keep.sum() >= 5 and keep[-1]
    p = stats.ttest_ind(a[:, keep], b[:, keep], equal_var=False).pvalue
    assert p.min() > 1e-3 / keep.sum(), (p.min(), keep.sum())


@pytest.mark.parametrize("params, message", [
    ({"allocation": "neyman"}, "allocation.*one of auto, uniform, adaptive"),
    ({"allocation": "adaptive", "share_beams": True}, "allocation.*uniform when share_beams is true")])
def test_refused_settings(mitsonar_mod, params, message):
    import mitsuba as mi

    with pytest.raises(Exception, match=message):
        mi.load_dict({"type": "sonar_tof", **params})
