"""Agreement with an independent renderer: mitransient's transient path tracer (DESIGN.md ladder 5).

mitransient renders, per camera pixel, the radiance that arrives at each optical path length.
With a point light of intensity 1 W/sr at the camera's centre, the radiance of a pixel
integrated over its solid angle and weighted by the two-way beam pattern is exactly what the
sonar's monostatic transducer receives from that direction, so
    sonar bin k = sum over pixels of L_pixel(OPL bin k) * solid_angle_pixel * B(d)^2
when mitransient's OPL bins are twice our range bins.
"""
import math

import numpy as np
import pytest

from conftest import frame_matrix, matrix_attr


@pytest.mark.slow
def test_single_bounce_lambertian_scene_agrees_with_mitransient(mitsonar_mod):
    import mitsuba as mi

    mitr = pytest.importorskip("mitransient")
    from mitsonar.plugins.sensors.beam import BeamPattern

    tilt = math.radians(40)
    frame = frame_matrix((math.sin(tilt), 0, -math.cos(tilt)), (0, 1, 0))
    x, y, z = frame[:3, 0], frame[:3, 1], frame[:3, 2]
    bw_h, bw_v, rho = 12.0, 20.0, 0.8
    r_min, r_max, n_bins = 1.5, 4.5, 60
    width = height = 200
    fov = 60.0
    plane = {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, -2]).scale([20, 20, 1]),
             "bsdf": {"type": "diffuse", "reflectance": {"type": "uniform", "value": rho}}}
    cam = mi.ScalarTransform4f().look_at(origin=[0, 0, 0], target=z.tolist(), up=y.tolist())

    def transient(seed):
        scene = mi.load_dict({
            "type": "scene",
            "integrator": {"type": "transient_path", "max_depth": 2, "camera_unwarp": False},
            # near_clip ~ 0: Mitsuba starts camera rays on the near plane, which would shorten
            # every optical path by near_clip.
            "sensor": {"type": "perspective", "fov": fov, "fov_axis": "x", "near_clip": 1e-6, "to_world": cam,
                       "film": {"type": "transient_hdr_film", "width": width, "height": height,
                                "temporal_bins": n_bins, "start_opl": 2 * r_min,
                                "bin_width_opl": 2 * (r_max - r_min) / n_bins, "rfilter": {"type": "box"}},
                       "sampler": {"type": "independent", "sample_count": 32}},
            "light": {"type": "point", "position": [0, 0, 0], "intensity": {"type": "uniform", "value": 1.0}},
            "plane": plane,
        })
        _, t = scene.integrator().render(scene, seed=seed)
        return np.array(t)[..., 0]  # (height, width, bins)

    # Solid angle and two-way beam gain of every pixel (the image's x runs along -x_cam).
    tan_h = math.tan(math.radians(fov / 2))
    px = -((np.arange(width) + 0.5) / width * 2 - 1) * tan_h
    py = ((np.arange(height) + 0.5) / height * 2 - 1) * tan_h * height / width
    PX, PY = np.meshgrid(px, py)
    norm = np.sqrt(PX ** 2 + PY ** 2 + 1)
    d_omega = (2 * tan_h / width) * (2 * tan_h / width) / norm ** 3
    beam = BeamPattern("gaussian", bw_h, bw_v)
    gain = beam.eval_np(np.arctan2(PX, np.ones_like(PX)), np.arcsin(PY / norm))
    weights = d_omega * gain ** 2
    assert weights[:, [0, -1]].max() < 1e-6 * weights.max(), "the camera must see the whole beam"
    runs_mt = np.stack([np.einsum("hw,hwt->t", weights, transient(s)) for s in range(3)])

    xml = f"""<scene version="3.0.0">
      <integrator type="sonar_tof"><integer name="max_depth" value="1"/></integrator>
      <sensor type="sonar"><transform name="to_world"><matrix value="{matrix_attr(frame)}"/></transform>
        <float name="beamwidth_h" value="{bw_h}"/><float name="beamwidth_v" value="{bw_v}"/>
        <float name="range_min" value="{r_min}"/><float name="range_max" value="{r_max}"/>
        <integer name="n_bins" value="{n_bins}"/><integer name="n_pings" value="1"/></sensor>
      <shape type="rectangle"><transform name="to_world"><translate z="-2"/><scale x="20" y="20"/></transform>
        <bsdf type="acoustic"><float name="diffuse" value="{rho}"/><float name="specular" value="0"/></bsdf></shape>
    </scene>"""
    scene = mitsonar_mod.load_scene(xml)
    runs = np.stack([mitsonar_mod.render_scan(scene, spp=1 << 18, seed=s).intensity[0].astype(np.float64)
                     for s in range(6)])

    ours, theirs = runs.mean(0), runs_mt.mean(0)
    err = np.sqrt(runs.var(0, ddof=1) / len(runs) + runs_mt.var(0, ddof=1) / len(runs_mt))
    assert ours.sum() == pytest.approx(theirs.sum(), rel=2e-3)
    lit = theirs > 1e-4 * theirs.max()
    assert lit.sum() > 20
    assert np.all(ours[theirs == 0] == 0)
    z = (ours[lit] - theirs[lit]) / np.maximum(err[lit], 3e-3 * theirs[lit])
    assert np.max(np.abs(z)) < 5.0, f"max |z| = {np.max(np.abs(z)):.2f}"
