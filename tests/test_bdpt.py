"""sonar_bdpt: unbiasedness against sonar_tof and the closed-form Lambert plane, strategy by
strategy; determinism; refused settings.

Statistics: every comparison is of means over independent seeds, with z = difference / combined
standard error of the means. With 10 seeds a z is t-distributed with about 9 degrees of freedom
(|z| > 6 has probability 2e-4), and the mean of z^2 over many cells is about 1.3; a biased
estimator (a wrong MIS weight, a missing or doubled strategy) moves whole ranges of bins by many
standard errors.
"""
import math
import os
import re

import numpy as np
import pytest

from conftest import SCENES, acoustic_xml, frame_matrix, rectangle_xml, scene_xml, sonar_xml
from test_physics import lambert_plane_reference, plane_matrix

SEEDS = range(10)


def load(mitsonar, name, n_pings=None, bearing_start=None):
    """A scene of scenes_xml/, with fewer pings when ``n_pings`` is given."""
    with open(os.path.join(SCENES, f"{name}.xml")) as fh:
        text = fh.read()
    if n_pings is not None:
        text = re.sub(r'(<integer name="n_pings" value=")\d+', rf"\g<1>{n_pings}", text)
    if bearing_start is not None:
        text = re.sub(r'(<float name="bearing_start" value=")[-0-9.]+', rf"\g<1>{bearing_start}", text)
    # a string has no folder: the meshes it names are found from scenes_xml/
    text = re.sub(r'(<string name="filename" value=")([^/"]+")', rf"\g<1>{SCENES}/\g<2>", text)
    return mitsonar.load_scene(text)


def integrator(**params):
    import mitsuba as mi

    return mi.load_dict(params)


def stats(integ, scene, spp, seeds=SEEDS, **kw):
    runs = np.stack([integ.render_histogram(scene, 0, seed=s, spp=spp, **kw) for s in seeds])
    return runs.mean(0), runs.std(0, ddof=1) / math.sqrt(len(runs))


def blocks(h, n):
    """Sum the range bins of each ping into ``n`` blocks: cells with many echoes each."""
    return h.reshape(h.shape[0], n, -1).sum(-1)


def z_scores(a, b, n_blocks, floor=2e-3):
    """z of the difference of two (mean, se) histograms in cells of ``n_blocks`` range blocks per
    ping, for the cells holding at least ``floor`` of the scene's energy. Cells of rare paths are
    left out: there (the box's far glossy multi-bounce echoes, say) both estimators are heavy
    tailed, a dozen seeds do not estimate their standard error, and even a 4M-path sonar_tof
    still moves by a factor of two."""
    (ma, sa), (mb, sb) = a, b
    runs_a, runs_b = blocks(ma, n_blocks), blocks(mb, n_blocks)
    se = np.sqrt(blocks(sa ** 2, n_blocks) + blocks(sb ** 2, n_blocks))  # upper bound of the blocks' se
    lit = np.maximum(runs_a, runs_b) > floor * runs_b.sum()
    return (runs_a[lit] - runs_b[lit]) / np.maximum(se[lit], 1e-6 * np.abs(runs_b[lit]) + 1e-30)


@pytest.mark.parametrize("name, n_pings, depth, mis", [
    ("box", 12, 3, "power"),
    ("glossy_corridor", 11, 5, "balance"),
    ("hidden_target", 21, 5, "power"),
    ("slot_chamber", 11, 5, "power"),
    ("box_fls", 16, 3, "power"),  # multibeam: subpath B leaves through the transmit fan
])
def test_agrees_with_sonar_tof(mitsonar_mod, name, n_pings, depth, mis):
    # The reference is BSDF-sampled (guide "none") like sonar_bdpt's subpaths: both estimate the
    # hidden boulder's echo from rare paths, with standard errors of a like kind; the image-guided
    # sonar_tof pins that echo to 2 % in ten seeds, where ten seeds of sonar_bdpt (heavy tailed
    # there) under-estimate their own spread (test_image_guide checks the guide itself).
    # box_fls cut to 16 rows: the middle ones, inside the (then 8.6 deg) transmit fan
    scene = load(mitsonar_mod, name, n_pings, bearing_start=-4 if name == "box_fls" else None)
    bd = stats(integrator(type="sonar_bdpt", max_depth=depth, mis=mis), scene, 128)
    tof = stats(integrator(type="sonar_tof", max_depth=depth, guide="none"), scene, 2048)
    z = z_scores(bd, tof, 25, 1e-3)
    assert len(z) >= 8
    assert np.max(np.abs(z)) < 6.0, f"max |z| = {np.max(np.abs(z)):.2f}"
    assert np.mean(z ** 2) < 2.5, f"mean z^2 = {np.mean(z ** 2):.2f}"
    total = [m.sum() for m, _ in (bd, tof)]
    se_total = math.hypot(*(s.sum() for _, s in (bd, tof)))  # the bins' se summed: an upper bound
    assert abs(total[0] - total[1]) < 4 * se_total


def test_hidden_boulder_echo_matches_sonar_tof(mitsonar_mod):
    """The boulder's echo (range >= 6.4 m, three bounces via the glossy plate), where path tracing
    is at its worst: bdpt's energy there agrees with sonar_tof's (z of the per-seed window sums)."""
    scene = load(mitsonar_mod, "hidden_target")
    window = int(6.4 / 10 * 400)

    def window_sums(name, spp):
        integ = integrator(type=name, max_depth=3, **({"guide": "none"} if name == "sonar_tof" else {}))
        e = np.array([integ.render_histogram(scene, 0, seed=s, spp=spp)[:, window:].sum() for s in SEEDS])
        return e.mean(), e.std(ddof=1) / math.sqrt(len(e))

    (eb, sb), (et, st) = window_sums("sonar_bdpt", 256), window_sums("sonar_tof", 4096)
    assert eb > 0 and et > 0
    assert abs(eb - et) < 4 * math.hypot(sb, st), (eb, sb, et, st)


def lambert_plane(mitsonar):
    """test_physics' ladder-1 scene (a uniform 20 x 30 deg beam tilted 40 deg onto a Lambertian
    plane 2 m below, one ping of 30 bins from 1.5 to 4.5 m) and its closed-form bins."""
    tilt = math.radians(40.0)
    bw_h, bw_v, height, rho = 20.0, 30.0, 2.0, 0.8
    boresight = (math.sin(tilt), 0.0, -math.cos(tilt))
    sensor = sonar_xml(frame_matrix(boresight, (0, 1, 0)), beam_pattern="uniform", beamwidth_h=bw_h,
                       beamwidth_v=bw_v, range_min=1.5, range_max=4.5, n_bins=30, n_pings=1, bearing_step=0.0)
    scene = mitsonar.load_scene(scene_xml(sensor, rectangle_xml(plane_matrix(-height), acoustic_xml(rho))))
    return scene, lambert_plane_reference(rho, height, tilt, math.radians(bw_h), math.radians(bw_v),
                                          np.linspace(1.5, 4.5, 31))


@pytest.mark.parametrize("strategy", ["0", "1", "all"])
def test_each_strategy_reproduces_the_lambert_plane(mitsonar_mod, strategy):
    """Single bounce on a Lambertian plane under a uniform beam (test_physics' closed form): the
    strategy from the transmit end (s = 1), the one from the receive end (s = 0), each alone and
    unweighted, and both MIS-weighted."""
    scene, ref = lambert_plane(mitsonar_mod)
    m, s = stats(integrator(type="sonar_bdpt", max_depth=1, strategy=strategy), scene, 1 << 12)
    m, s = m[0], s[0]
    lit = ref > 1e-3 * ref.max()
    assert lit.sum() >= 8
    assert np.all(m[ref == 0] == 0)
    z = (m[lit] - ref[lit]) / np.maximum(s[lit], 1e-4 * ref[lit])
    assert np.max(np.abs(z)) < 6.0, f"max |z| = {np.max(np.abs(z)):.2f}"
    assert abs(m.sum() - ref.sum()) < 4 * s.sum() + 2e-3 * ref.sum()


def test_strategies_split_the_paths_by_bounce(mitsonar_mod):
    """On the box with two bounces, strategy s = 2 alone carries exactly the two-bounce paths:
    sonar_tof(max_depth 2) - sonar_tof(max_depth 1); s = 1 alone carries all of them."""
    scene = load(mitsonar_mod, "box", 6)
    two = stats(integrator(type="sonar_bdpt", max_depth=2, strategy="2"), scene, 256)
    one = stats(integrator(type="sonar_bdpt", max_depth=2, strategy="1"), scene, 256)
    tof = integrator(type="sonar_tof", max_depth=2)
    runs = [tof.render_histogram(scene, 0, seed=s, spp=2048, max_depth=d) for s in SEEDS for d in (1, 2)]
    diff = np.stack([runs[2 * i + 1] - runs[2 * i] for i in range(len(SEEDS))])
    full = np.stack([runs[2 * i + 1] for i in range(len(SEEDS))])
    for bd, ref in ((two, diff), (one, full)):
        z = z_scores(bd, (ref.mean(0), ref.std(0, ddof=1) / math.sqrt(len(ref))), 10)
        assert np.max(np.abs(z)) < 6.0 and np.mean(z ** 2) < 2.5, (np.max(np.abs(z)), np.mean(z ** 2))
    assert two[0].sum() < 0.2 * one[0].sum()  # the two-bounce echoes are the smaller part


def test_same_seed_same_scan(mitsonar_mod):
    """Same seed, same scan (the float32 intensity a Scan holds: the float64 bins' last bits
    depend on the order threads add echoes, as in sonar_tof); another seed, another scan."""
    scene = load(mitsonar_mod, "glossy_corridor", 5)
    integ = integrator(type="sonar_bdpt", max_depth=4)
    a, b, c = (integ.render_histogram(scene, 0, seed=seed, spp=128).astype(np.float32) for seed in (3, 3, 4))
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    assert a.sum() > 0


@pytest.mark.parametrize("params, message", [
    ({"max_depth": 0}, r"sonar_bdpt 'max_depth': 0 is not allowed"),
    ({"max_depth": 65}, r"sonar_bdpt 'max_depth': 65 is not allowed"),
    ({"mis": "veach"}, r"sonar_bdpt 'mis': 'veach' is not allowed \(one of balance, power\)"),
    ({"strategy": "6"}, r"sonar_bdpt 'strategy': '6' is not allowed"),
    ({"strategy": "two"}, r"sonar_bdpt 'strategy': 'two' is not allowed"),
    # no shared multibeam paths to weight: sonar_tof's default would be silently ignored
    ({"emission": "receive"}, r"sonar_bdpt 'emission': 'receive' is not allowed \(one of transmit\)"),
])
def test_bad_settings_are_refused(mitsonar_mod, params, message):
    sensor = sonar_xml(n_pings=1, n_bins=4)
    attrs = "".join(f'<integer name="{k}" value="{v}"/>' if isinstance(v, int) else f'<string name="{k}" value="{v}"/>'
                    for k, v in params.items())
    with pytest.raises(mitsonar_mod.SceneError, match=message):
        mitsonar_mod.load_scene(scene_xml(sensor, integrator=f'<integrator type="sonar_bdpt">{attrs}</integrator>'))


def test_bad_max_depth_at_render_time(mitsonar_mod):
    scene = load(mitsonar_mod, "box", 2)
    integ = integrator(type="sonar_bdpt")
    for bad in (0, 65):
        with pytest.raises(ValueError, match=r"sonar_bdpt 'max_depth'"):
            integ.render_histogram(scene, 0, spp=4, max_depth=bad)


@pytest.mark.parametrize("name, n_pings, depth, bearing_start", [
    ("intake", 20, 3, None),
    ("harbour", 16, 3, None),
    ("quay_wall", 32, 2, -4),        # the 32 middle beams: the quay and the piles
    ("rocky_slope", 32, 2, -11),
    ("wreck", 10, 3, None),
    ("wreck_sidescan", 10, 2, None),
])
def test_agrees_with_sonar_tof_on_the_other_scenes(mitsonar_mod, name, n_pings, depth, bearing_start):
    """The rest of scenes_xml/ (fewer rows, at most the scene's own max_depth): survey scenes with
    meshes, multibeam, side-scan and mechanical heads; the same bounds as above. (The periscope is
    left out: without the image guide neither estimator resolves its double-mirror paths in ten
    seeds; sonar_bdpt's total there agrees with the guided sonar_tof's to 0.1 %.)"""
    scene = load(mitsonar_mod, name, n_pings, bearing_start=bearing_start)
    bd = stats(integrator(type="sonar_bdpt", max_depth=depth), scene, 64)
    tof = stats(integrator(type="sonar_tof", max_depth=depth, guide="none"), scene, 512)
    z = z_scores(bd, tof, 25, 1e-3)
    assert len(z) >= 8
    assert np.max(np.abs(z)) < 6.0, f"max |z| = {np.max(np.abs(z)):.2f}"
    assert np.mean(z ** 2) < 2.5, f"mean z^2 = {np.mean(z ** 2):.2f}"
    se_total = math.hypot(*(s.sum() for _, s in (bd, tof)))
    assert abs(bd[0].sum() - tof[0].sum()) < 4 * se_total
