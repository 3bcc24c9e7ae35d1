"""Render the pictures of the documentation (docs/_static/*.png): small, palette-quantised PNGs.

Run by hand when the renderer's output changes (the docs build never renders):

    .venv/bin/python docs/make_images.py

Each picture's code is the code shown on the gallery page (docs/gallery.rst).
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

import mitsonar
from mitsonar import plots

ROOT = Path(__file__).resolve().parent.parent
STATIC = ROOT / "docs" / "_static"
SCENES = ROOT / "scenes_xml"


def save_small(fig_or_path, name: str, colors: int = 96) -> None:
    """Quantise a PNG written by a plot function into docs/_static/<name>."""
    from PIL import Image

    im = Image.open(fig_or_path).convert("RGB").quantize(colors=colors)
    im.save(STATIC / name, optimize=True)
    print(f"wrote {STATIC / name} ({(STATIC / name).stat().st_size // 1024} KiB)")


def main(only=()) -> None:
    tmp = Path(tempfile.mkdtemp())
    small = dict(figsize=(5.0, 4.6), dpi=100)

    def want(name):
        return not only or name in only

    if want("box_scan.png") or want("box_top.png") or want("box_ascan.png"):
        scene = mitsonar.load_scene(str(SCENES / "box.xml"))
        scan = mitsonar.render_scan(scene, spp=4096, seed=0)
        if want("box_scan.png"):
            plots.plot_polar(scan, tmp / "a.png", resolution=500, **small)
            save_small(tmp / "a.png", "box_scan.png", 64)
        if want("box_top.png"):
            plots.plot_cartesian(scan, mesh=mitsonar.scene_mesh(scene), path=tmp / "b.png", **small)
            save_small(tmp / "b.png", "box_top.png")
        if want("box_ascan.png"):
            plots.plot_ascan(scan, 0, tmp / "c.png", db=True, figsize=(6.0, 3.2), dpi=100)
            save_small(tmp / "c.png", "box_ascan.png")
    if want("box_fls.png"):
        scene = mitsonar.load_scene(str(SCENES / "box_fls.xml"))
        frame = mitsonar.render_scan(scene, spp=256, seed=0)
        plots.plot_polar(frame, tmp / "d.png", resolution=500, **small)
        save_small(tmp / "d.png", "box_fls.png")
    if want("box_moving.png"):
        scene = mitsonar.load_scene(str(SCENES / "box.xml"))
        track = mitsonar.Trajectory.turn(30.0, 0.3, 6.0)
        scan = mitsonar.render_scan(scene, trajectory=track, start_time=2.0, spp=1024)
        plots.plot_cartesian(scan, mesh=mitsonar.scene_mesh(scene), path=tmp / "e.png", **small)
        save_small(tmp / "e.png", "box_moving.png")
    if want("wreck_waterfall.png"):
        from mitsonar.products import sidescan_plots

        scene = mitsonar.load_scene(str(SCENES / "wreck_sidescan.xml"))
        track = mitsonar.Trajectory.from_tum(SCENES / "wreck_sidescan_survey.tum")
        scans = list(mitsonar.render_survey(scene, track, spp=64, max_scans=3, progress=False))
        sidescan_plots.plot_waterfall(scans[2], tmp / "f.png", figsize=(6.0, 4.0), dpi=100)
        save_small(tmp / "f.png", "wreck_waterfall.png")
    if want("box_map.png"):
        from hilbertmap import HilbertMap
        from hilbertmap.plots import plot_slices

        scene = mitsonar.load_scene(str(SCENES / "box.xml"))
        scan = mitsonar.render_scan(scene, spp=4096, seed=0)
        hm = HilbertMap(random_state=0).fit([scan])                 # about 40 s on 2 cores
        plot_slices(hm, truth=mitsonar.scene_mesh(scene), path=tmp / "g.png")
        save_small(tmp / "g.png", "box_map.png")
    if want("tl_thermocline.png"):
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        from mitsonar.acoustics import SoundSpeedProfile, transmission_loss_field

        thermocline = SoundSpeedProfile([0.0, 30.0, 100.0], [1520.0, 1480.0, 1480.0])
        depths, ranges = np.linspace(0.5, 99.5, 100), np.linspace(10.0, 2000.0, 200)
        tl = transmission_loss_field(thermocline, 10.0, depths, ranges, water_depth=100.0, frequency=10e3,
                                     angles=(-80.0, 80.0), rays=4001, max_bounces=20)
        fig, ax = plt.subplots(figsize=(6.4, 3.4), dpi=100)
        im = ax.pcolormesh(ranges, depths, tl, vmin=40, vmax=70, cmap="jet_r", shading="nearest")
        ax.invert_yaxis()
        ax.set_xlabel("range (m)")
        ax.set_ylabel("depth (m)")
        ax.set_title("incoherent TL, source at 10 m, 1520 to 1480 m/s over 30 m")
        fig.colorbar(im, ax=ax, label="TL (dB re 1 m)")
        fig.tight_layout()
        fig.savefig(tmp / "h.png")
        plt.close(fig)
        save_small(tmp / "h.png", "tl_thermocline.png", 160)
    if want("sas_psf.png"):
        save_small(_sas_psf(tmp / "h.png"), "sas_psf.png")
    if want("volumetric_widths.png"):
        save_small(_volumetric_widths(tmp / "i.png"), "volumetric_widths.png")
    if want("sas_cylinder.png"):
        sys.path.insert(0, str(ROOT / "examples"))
        import sas_cylinder

        sas_cylinder.main([str(tmp)])                                # about 20 s on 2 cores
        save_small(tmp / "sas_cylinder.png", "sas_cylinder.png", 24)


def _sas_psf(path):
    """The point target at 8 m of docs/tutorials/sas.rst, focused with uniform weighting."""
    import math

    from mitsonar import sas
    from mitsonar.signals import PointTarget

    cfg = sas.StripMap(n_elements=8, element_length=0.06, frequency=100e3, bandwidth=30e3, speed=3.6,
                       ping_period=0.05, range_max=20.0)
    scene = mitsonar.load_scene('<scene version="3.0.0"><integrator type="sonar_tof"/>'
                                + cfg.sensor_xml(flat=True, n_pings=36, depression=30.0,
                                                 beamwidth_v=80.0) + "</scene>")
    target = PointTarget((3.6, math.sqrt(64.0 - 9.0), 0.0), 0.0)
    echoes = mitsonar.render_echoes(scene, cfg.pulse(), elements=cfg.elements(), spp=1,
                                    trajectory=cfg.track(1.9, start=(0.0, 0.0, 3.0)), start_time=0.0,
                                    targets=[target])
    image = sas.form_image(echoes, sas.Grid.around(target.position, 0.12, 0.12, 0.002))
    sas.plot_psf(image, path, title="SAS point target at 8 m: D = 6 cm, 100 kHz, 30 kHz band, uniform weighting")
    return path


def _volumetric_widths(path):
    """-3 dB azimuth widths of the 24 x 24 array of docs/tutorials/volumetric.rst steered 0 to 50
    deg, measured on a point target at 3 m against 0.886 lambda / (N d cos steer)."""
    import math

    from matplotlib.figure import Figure

    from mitsonar.sas.quality import _cut
    from mitsonar.signals import PointTarget
    from mitsonar.signals import volumetric as V

    head = V.Volumetric(rows=24, columns=24, frequency=200e3, bandwidth=20e3, n_azimuth=31, n_elevation=21,
                        fov_azimuth=110.0, fov_elevation=40.0, range_max=4.0, n_bins=370, range_min=0.3)
    scene = mitsonar.load_scene('<scene version="3.0.0"><integrator type="sonar_tof"/>' + head.sensor_xml()
                                + "</scene>")
    steers = np.arange(0, 51, 5)
    step = math.radians(0.05)
    fine = np.arange(-300, 301) * step
    measured = []
    for s in steers:
        az = math.radians(s)
        u = V.directions([az], [0.0])[0, 0]
        e = mitsonar.render_echoes(scene, head.pulse(), elements=head.elements(), spp=1,
                                   targets=[PointTarget(tuple(3.0 * u), 0.0)])
        cut = V.beamform_3d(e, az + fine, [0.0], [3.0]).intensity[0, :, 0]
        measured.append(math.degrees(_cut(cut, int(np.argmax(cut)), step)[0]))
    fig = Figure(figsize=(5.0, 3.2), dpi=100, layout="constrained")
    ax = fig.add_subplot(1, 1, 1)
    theory = [math.degrees(head.beamwidths(math.radians(s))[0]) for s in np.arange(0, 51)]
    ax.plot(np.arange(0, 51), theory, label="0.886 lambda / (N d cos steer)")
    ax.plot(steers, measured, "o", label="beamform_3d, point target at 3 m")
    ax.set_xlabel("steering angle (deg)")
    ax.set_ylabel("-3 dB azimuth width (deg)")
    ax.legend(fontsize=7, frameon=False)
    fig.savefig(path, dpi=100)
    return path


if __name__ == "__main__":
    main(tuple(sys.argv[1:]))
