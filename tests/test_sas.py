"""Point targets and strip-map SAS (`mitsonar.sas`): closed-form resolutions, the DPCA condition,
navigation errors that defocus, one kernel for every call."""
import math
import warnings

import numpy as np
import pytest

from conftest import frame_matrix, jit_kernels, scene_xml, sonar_xml

H = 3.0           # altitude of the SAS track over the targets' plane z = 0
XT = 3.6          # along-track position of the targets


def strip_map(**kw):
    from mitsonar import sas

    args = dict(n_elements=8, element_length=0.06, frequency=100e3, bandwidth=30e3, speed=4.0, ping_period=0.05,
                range_max=20.0)
    args.update(kw)
    return sas.StripMap(**args)


def target_at(slant, ts=0.0):
    from mitsonar.signals import PointTarget

    return PointTarget((XT, math.sqrt(slant * slant - H * H), 0.0), ts)


@pytest.fixture(scope="module")
def sas_run(mitsonar_mod):
    """36 pings of an 8-element, 100 kHz, 30 kHz-band SAS (D = 6 cm, 0.2 m per ping, DPCA kept)
    past three unit targets at slant ranges 4, 8 and 16 m (4x); a flat transmit beam over twice
    lambda / D so the processed beam sees a flat aperture."""
    return three_targets(mitsonar_mod, strip_map())


def three_targets(mitsonar, cfg):
    """``cfg``'s 36 pings past the unit targets at slant ranges 4, 8 and 16 m (the flat transmit
    beam, 30 deg down): ``(cfg, scene, targets, track, echoes)``."""
    scene = mitsonar.load_scene(scene_xml(cfg.sensor_xml(flat=True, n_pings=36, depression=30.0,
                                                         beamwidth_v=80.0)))
    targets = [target_at(r) for r in (4.0, 8.0, 16.0)]
    track = cfg.track(1.9, start=(0.0, 0.0, H))
    echoes = mitsonar.render_echoes(scene, cfg.pulse(), elements=cfg.elements(), spp=1, trajectory=track,
                                    start_time=0.0, targets=targets)
    return cfg, scene, targets, track, echoes


# ------------------------------------------------------------------------------ point targets
def test_point_target_echo_is_the_sonar_equation_and_deterministic(mitsonar_mod):
    """One element at the transmitter, a target of TS on the axis at r: the compressed echo peaks at
    10^((SL + TS) / 20) / r^2 uPa, the same bytes for any path or speckle seed, 6 dB more TS twice
    the amplitude."""
    from mitsonar import signals as S

    sensor = sonar_xml(frame_matrix((1, 0, 0), (0, 0, 1)), n_pings=1, n_bins=100, range_max=8.0,
                       beam_pattern="uniform", beamwidth_h=10.0, beamwidth_v=10.0, source_level=200.0)
    scene = mitsonar_mod.load_scene(scene_xml(sensor))
    p = S.lfm(690e3, 710e3, 1e-3)
    r, ts = 5.0, -20.0
    run = lambda tgt, **kw: mitsonar_mod.render_echoes(scene, p, spp=1, sample_rate=8 * p.bandwidth,  # noqa: E731
                                                       targets=tgt, **kw)
    a = run(S.PointTarget((r, 0.0, 0.0), ts))
    y = np.abs(S.matched_filter(a.signal[0, 0], p, a.sample_rate))
    assert y.max() == pytest.approx(10 ** ((200.0 + ts) / 20) / r ** 2, rel=0.02)
    assert abs(int(np.argmax(y)) - 2 * r / 1500.0 * a.sample_rate) <= 1
    b = run([S.PointTarget((r, 0.0, 0.0), ts)], seed=3, speckle_seed=7)
    assert a.signal.tobytes() == b.signal.tobytes()
    c = run(S.PointTarget((r, 0.0, 0.0), ts + 20 * math.log10(2)))
    assert np.abs(S.matched_filter(c.signal[0, 0], p, c.sample_rate)).max() == pytest.approx(2 * y.max(), rel=1e-4)
    # outside the uniform transmit beam: no echo
    d = run(S.PointTarget((0.0, r, 0.0), ts))
    assert np.abs(d.signal).max() == 0.0


@pytest.mark.parametrize("bad", ["nope", [(1.0, 2.0, 3.0)], 5])
def test_bad_targets_are_refused_in_one_line(mitsonar_mod, bad):
    from mitsonar import signals as S
    from mitsonar.sim.scene import SceneError

    scene = mitsonar_mod.load_scene(scene_xml(sonar_xml(n_pings=1, n_bins=10, range_max=4.0)))
    with pytest.raises(SceneError, match="'targets'") as err:
        mitsonar_mod.render_echoes(scene, S.lfm(690e3, 710e3, 1e-3), spp=1, targets=bad)
    assert "\n" not in str(err.value)
    with pytest.raises(SceneError, match="'targets'"):
        mitsonar_mod.render_echoes(scene, S.lfm(690e3, 710e3, 1e-3), spp=1,
                                   targets=S.PointTarget((1.0, math.nan, 0.0), 0.0))


# ------------------------------------------------------------------------------ configuration
def test_strip_map_closed_forms_and_the_dpca_condition():
    from mitsonar import sas

    cfg = strip_map()
    assert cfg.wavelength == pytest.approx(0.015) and cfg.beamwidth == pytest.approx(0.25)
    assert cfg.dpca_advance == pytest.approx(0.24) and cfg.dpca_ok and cfg.overlap == 1
    assert cfg.along_track_resolution() == pytest.approx(0.886 * 0.015 / (4 * math.sin(0.125)))
    assert cfg.along_track_resolution() == pytest.approx(0.886 * 0.06 / 2, rel=0.01)      # ~ k_w D / 2
    assert cfg.range_resolution() == pytest.approx(0.886 * 1500 / 60e3)
    assert cfg.range_resolution(math.radians(60)) == pytest.approx(2 * cfg.range_resolution())
    assert cfg.synthetic_aperture(8.0) == pytest.approx(2.0)
    assert cfg.max_speed == pytest.approx(0.24 / (40 / 1500))
    with pytest.warns(sas.SASWarning, match="DPCA"):
        fast = strip_map(speed=5.0)
    assert not fast.dpca_ok
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        strip_map(speed=4.8)                                 # exactly N D / 2 per ping: no warning
    with pytest.raises(ValueError, match="'ping_period'.*two-way flight"):
        strip_map(ping_period=0.02)
    with pytest.raises(ValueError, match="'n_elements'"):
        strip_map(n_elements=0)
    els = cfg.elements()
    assert els.shape == (8, 3) and np.allclose(np.diff(els[:, 0]), 0.06) and els[:, 0].mean() == pytest.approx(0)


# ------------------------------------------------------------------------------ image formation
def test_along_track_resolution_is_the_closed_form_at_three_ranges_and_across_track_is_c_over_2b(sas_run):
    """Uniform weighting over the processed beam lambda / D: along track 0.886 lambda / (4 sin(theta/2))
    (~0.886 D / 2) at 4, 8 and 16 m alike (a real aperture's would grow 4x); across track on the
    ground grid 0.886 c / (2 B) / cos(grazing); each peak within a pixel or two of the target; PSLR near
    the sinc's -13.3 dB."""
    from mitsonar import sas

    cfg, _, targets, _, echoes = sas_run
    data = sas.compressed(echoes)
    for t in targets:
        slant = float(np.linalg.norm(np.array(t.position) - (XT, 0.0, H)))
        image = sas.form_image(echoes, sas.Grid.around(t.position, 0.12, 0.12, 0.002), data=data)
        f = sas.psf(image)
        assert f["along"] == pytest.approx(cfg.along_track_resolution(), rel=0.10), slant
        assert f["across"] == pytest.approx(cfg.range_resolution(math.asin(H / slant)), rel=0.10), slant
        assert abs(f["peak"][0] - XT) < 0.3 * cfg.along_track_resolution()
        assert abs(f["peak"][1] - t.position[1]) < 0.3 * cfg.range_resolution()
        assert -15.0 < f["pslr_along"] < -11.0 and -15.0 < f["pslr_across"] < -11.0
        assert f["islr_along"] < -8.0
        assert image.meta["pixel_pairs"] > 0 and image.meta["window"] == "uniform"


def test_hann_weighting_widens_the_peak_by_its_factor_and_a_narrower_beam_coarsens_it(sas_run):
    from mitsonar import sas

    cfg, _, targets, _, echoes = sas_run
    grid = sas.Grid.around(targets[1].position, 0.15, 0.04, 0.002)
    hann = sas.psf(sas.form_image(echoes, grid, window="hann"))
    assert hann["along"] == pytest.approx(cfg.along_track_resolution(window="hann"), rel=0.10)
    assert hann["pslr_along"] < -25.0
    half = sas.psf(sas.form_image(echoes, grid, beamwidth=cfg.beamwidth / 2))
    assert half["along"] == pytest.approx(cfg.along_track_resolution(beamwidth=cfg.beamwidth / 2), rel=0.10)


def test_sway_of_a_quarter_wavelength_defocuses_and_the_true_navigation_refocuses(mitsonar_mod, sas_run):
    """A sinusoidal sway of lambda / 4 over the synthetic aperture at 8 m, focused with the straight
    track as navigation: the peak drops by more than 3 dB; with the true (swaying) track as navigation
    it is the unswayed peak within 0.5 dB; a 1 % wrong sound speed moves the peak across track."""
    from mitsonar import sas

    cfg, scene, targets, track, echoes = sas_run
    L = cfg.synthetic_aperture(8.0)
    swaying = cfg.track(1.9, start=(0.0, 0.0, H),
                        sway=lambda x: cfg.wavelength / 4 * np.sin(2 * np.pi * (x - XT) / L))
    swayed = mitsonar_mod.render_echoes(scene, cfg.pulse(), elements=cfg.elements(), spp=1, trajectory=swaying,
                                        start_time=0.0, targets=[targets[1]])
    grid = sas.Grid.around(targets[1].position, 0.1, 0.06, 0.002)
    ref = sas.psf(sas.form_image(echoes, grid))["peak_power"]
    straight_nav = sas.psf(sas.form_image(swayed, grid, navigation=track))
    true_nav = sas.psf(sas.form_image(swayed, grid, navigation=swaying))
    assert 10 * math.log10(straight_nav["peak_power"] / ref) < -3.0
    assert abs(10 * math.log10(true_nav["peak_power"] / ref)) < 0.5
    slow = sas.psf(sas.form_image(echoes, grid, sound_speed=1.01 * cfg.sound_speed))
    assert slow["peak"][1] - targets[1].position[1] > 0.5 * 0.01 * 8.0


def test_form_image_refusals_and_one_kernel_for_every_call(sas_run):
    from mitsonar import sas

    cfg, _, targets, track, echoes = sas_run
    grid = sas.Grid.around(targets[0].position, 0.02, 0.02, 0.004)
    for kw, name in (({"window": "kaiser"}, "'window'"), ({"beamwidth": 4.0}, "'beamwidth'"),
                     ({"upsample": 0}, "'upsample'"), ({"sound_speed": -1.0}, "'sound_speed'")):
        with pytest.raises(ValueError, match=name):
            sas.form_image(echoes, grid, **kw)
    with pytest.raises(ValueError, match="'grid'"):
        sas.form_image(echoes, grid.points())
    short = cfg.track(0.5, start=(0.0, 0.0, H))
    with pytest.raises(ValueError, match="'navigation'.*span"):
        sas.form_image(echoes, grid, navigation=short)
    data = sas.compressed(echoes)
    first, _ = jit_kernels(sas.form_image, echoes, grid, data=data)
    other = sas.Grid.around(targets[2].position, 0.03, 0.01, 0.003)      # tiles of 1 to 6 points
    again, _ = jit_kernels(sas.form_image, echoes, other, data=data, chunk=7, sound_speed=1490.0,
                           navigation=track, beamwidth=0.2)
    assert again and set(again) <= set(first)
    # chunking (each chunk its own float32 origin and its own pairs) changes the image only by the
    # float32 rounding of the geometry: a few 1e-3 rad of phase
    a = sas.form_image(echoes, other, data=data).image
    b = sas.form_image(echoes, other, data=data, chunk=5).image
    assert np.abs(a - b).max() < 5e-3 * np.abs(a).max()


@pytest.mark.parametrize("side", ["port", "starboard"])
def test_dpca_micronavigation_recovers_the_sway_and_refocuses(mitsonar_mod, side):
    """0.18 m per ping (6 half receivers: 2 shared phase centres a ping), a field of weak point
    scatterers on the seabed and a unit target at 8 m, the track swaying lambda / 4 over the synthetic
    aperture: the straight navigation loses more than 3 dB; the DPCA estimate follows the true sway
    within lambda / 20 and brings the peak back within 1 dB of the true navigation's. Advances that
    share no phase centre are refused. On either side (a starboard channel's beam frame x points
    aft)."""
    from mitsonar import sas
    from mitsonar.signals import PointTarget

    cfg = strip_map(speed=3.6)
    assert cfg.overlap == 2
    sign = 1.0 if side == "port" else -1.0
    scene = mitsonar_mod.load_scene(scene_xml(cfg.sensor_xml(side=side, flat=True, n_pings=36,
                                                             depression=30.0, beamwidth_v=80.0)))
    rng = np.random.default_rng(1)
    field = [PointTarget((x, sign * y, 0.0), -20.0)
             for x, y in zip(rng.uniform(-1, 8, 200), rng.uniform(4, 14, 200))]
    t8 = target_at(8.0)
    target = PointTarget((t8.position[0], sign * t8.position[1], 0.0), 0.0)
    L = cfg.synthetic_aperture(8.0)
    straight = cfg.track(1.9, start=(0.0, 0.0, H))
    swaying = cfg.track(1.9, start=(0.0, 0.0, H),
                        sway=lambda x: cfg.wavelength / 4 * np.sin(2 * np.pi * (x - XT) / L))
    echoes = mitsonar_mod.render_echoes(scene, cfg.pulse(), elements=cfg.elements(), spp=1, trajectory=swaying,
                                        start_time=0.0, targets=[target] + field)
    grid = sas.Grid.around(target.position, 0.1, 0.06, 0.002)
    data = sas.compressed(echoes)
    ref = sas.psf(sas.form_image(echoes, grid, navigation=swaying, data=data))["peak_power"]
    lost = sas.psf(sas.form_image(echoes, grid, navigation=straight, data=data))["peak_power"]
    assert 10 * math.log10(lost / ref) < -3.0
    nav = sas.micronavigation(echoes, straight)
    t = echoes.meta["start_time"] + echoes.times
    truth = swaying.at(t)[:, 1, 3] - swaying.at(t[:1])[0, 1, 3]
    assert np.max(np.abs(nav.at(t)[:, 1, 3] - truth)) < cfg.wavelength / 20
    found = sas.psf(sas.form_image(echoes, grid, navigation=nav, data=data))["peak_power"]
    assert abs(10 * math.log10(found / ref)) < 1.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        apart = strip_map(speed=4.0)                 # 0.2 m a ping: 6.67 half receivers
    track = apart.track(1.9, start=(0.0, 0.0, H))
    moved = mitsonar_mod.render_echoes(scene, cfg.pulse(), elements=cfg.elements(), spp=1, trajectory=track,
                                       start_time=0.0, targets=[target])
    with pytest.raises(ValueError, match="micronavigation 'echoes'.*whole number"):
        sas.micronavigation(moved)


def test_sas_image_as_geotiff_in_the_surveys_crs(sas_run, tmp_path):
    """North-up, pixel centres where the grid's are, the peak's dB value at the target's cell, the
    frame's CRS and origin."""
    import rasterio

    from mitsonar import sas
    from mitsonar.geometry.geodesy import GeoFrame

    _, _, targets, _, echoes = sas_run
    grid = sas.Grid(XT + np.arange(-10, 11) * 0.01, targets[1].position[1] + np.arange(-5, 8) * 0.01, 0.0)
    image = sas.form_image(echoes, grid)
    frame = GeoFrame.make((43.0, 5.0), "EPSG:32631")
    sas.write_sas_geotiff(tmp_path / "sas.tif", image, frame)
    with rasterio.open(tmp_path / "sas.tif") as src:
        band = src.read(1)
        assert src.crs.to_epsg() == 32631 and band.shape == (13, 21)
        i, j = np.unravel_index(int(np.argmax(np.abs(image.image))), image.image.shape)
        row, col = src.index(grid.x[i] + frame.e0, grid.y[j] + frame.n0)
        assert band[row, col] == pytest.approx(20 * np.log10(np.abs(image.image[i, j])), abs=1e-3)
        assert band[row, col] == np.nanmax(band)
        assert src.descriptions == ("intensity",)
    with pytest.raises(ValueError, match="'image'"):
        sas.write_sas_geotiff(tmp_path / "x.tif", sas.SASImage(image.image[:1], sas.Grid(grid.x[:1], grid.y), {}))


def test_psf_figure_is_written(sas_run, tmp_path):
    from mitsonar import sas

    _, _, targets, _, echoes = sas_run
    image = sas.form_image(echoes, sas.Grid.around(targets[0].position, 0.08, 0.08, 0.004))
    fig = sas.plot_psf(image, tmp_path / "psf.png", title="4 m")
    assert (tmp_path / "psf.png").stat().st_size > 1000
    legend = [t.get_text() for t in fig.axes[1].get_legend().get_texts()]
    assert legend[0].startswith("along: ") and "PSLR" in legend[1]
    with pytest.raises(ValueError, match="extension"):
        sas.plot_psf(image, tmp_path / "psf.txt")
    assert not (tmp_path / "psf.txt").exists()


def test_cylinder_example_shows_its_highlight_and_shadow(tmp_path):
    """examples/sas_cylinder.py at a small spp: the files are written; along the cylinder, its
    shadow (8.5 to 9.4 m across) is 6 dB darker than the same ranges of open seabed beyond its ends,
    its highlight (7.6 to 7.8 m) brighter than them."""
    from conftest import example

    image = example("sas_cylinder").main([str(tmp_path), "--spp", "2048"])
    assert (tmp_path / "sas_cylinder.png").stat().st_size > 1000 and (tmp_path / "sas_cylinder.tif").exists()
    g, p = image.grid, np.abs(image.image.astype(np.complex128)) ** 2

    def mean(x0, x1, y0, y1):
        return p[np.ix_((g.x >= x0) & (g.x <= x1), (g.y >= y0) & (g.y <= y1))].mean()

    beside = 0.5 * (mean(1.7, 2.3, 8.5, 9.4) + mean(4.9, 5.5, 8.5, 9.4))
    assert mean(2.9, 4.3, 8.5, 9.4) < beside / 4
    assert mean(2.9, 4.3, 7.6, 7.8) > 0.5 * (mean(1.7, 2.3, 7.6, 7.8) + mean(4.9, 5.5, 7.6, 7.8))


def test_omega_k_matches_backprojection_and_the_closed_forms(mitsonar_mod):
    """The wavenumber processor on a straight track, 0.18 m a ping (phase centres shared by
    consecutive pings taken once): at 4, 8 and 16 m the peak where backprojection puts it, the
    along-track width within 10 % of the closed form, across track within 10 % of c / (2 B) on the
    ground, the complex images alike (normalised correlation > 0.95). A swaying navigation and an
    advance that leaves the phase centres off a uniform grid are refused."""
    from mitsonar import sas

    cfg, scene, targets, track, echoes = three_targets(mitsonar_mod, strip_map(speed=3.6))
    for t in targets:
        slant = float(np.linalg.norm(np.array(t.position) - (XT, 0.0, H)))
        grid = sas.Grid.around(t.position, 0.1, 0.1, 0.002)
        wk, bp = sas.omega_k(echoes, grid), sas.form_image(echoes, grid)
        f, g = sas.psf(wk), sas.psf(bp)
        assert np.hypot(f["peak"][0] - g["peak"][0], f["peak"][1] - g["peak"][1]) <= 0.0045
        assert f["along"] == pytest.approx(cfg.along_track_resolution(), rel=0.10), slant
        assert f["across"] == pytest.approx(cfg.range_resolution(math.asin(H / slant)), rel=0.10), slant
        a, b = wk.image.ravel(), bp.image.ravel()
        assert abs(np.vdot(a, b)) / np.linalg.norm(a) / np.linalg.norm(b) > 0.95
        assert wk.meta["processor"] == "omega_k"
    swaying = cfg.track(1.9, start=(0.0, 0.0, H), sway=lambda x: 0.01 * np.sin(x))
    with pytest.raises(ValueError, match="omega_k 'navigation'.*straight"):
        sas.omega_k(echoes, grid, navigation=swaying)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        apart = strip_map(speed=4.0)
    off = mitsonar_mod.render_echoes(scene, cfg.pulse(), elements=cfg.elements(), spp=1, start_time=0.0,
                                     trajectory=apart.track(1.9, start=(0.0, 0.0, H)), targets=targets[:1])
    with pytest.raises(ValueError, match="omega_k 'echoes'.*uniform along-track grid"):
        sas.omega_k(off, grid)
