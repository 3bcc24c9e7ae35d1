"""Speed of the 3D imaging sonar's two paths (`mitsonar.signals.volumetric`): prints JSON.

A rough plane 2 m in front of a planar array (default 24 x 24 at half a wavelength, 200 kHz, 20 kHz
band) seen in ``--beams`` x ``--beams`` beams over 30 x 30 deg and 135 range bins: the coherent
frame (`render_echoes` of every element, then `beamform_3d`) against the incoherent fast path
(`render_volume`: the same echo paths scored into every beam by the array's pattern), each at
``--spp`` paths. One coherent frame is one speckle realisation; the fast path is the mean.

    python benchmarks/volumetric_speed.py [--elements 24] [--beams 11] [--spp 32768]
"""
from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--elements", type=int, default=24, help="rows = columns of the array")
    ap.add_argument("--beams", type=int, default=11, help="beams per axis")
    ap.add_argument("--spp", type=int, default=1 << 15)
    args = ap.parse_args(argv)
    import mitsonar
    from mitsonar.signals import volumetric as V

    head = V.Volumetric(rows=args.elements, columns=args.elements, frequency=200e3, bandwidth=20e3,
                        n_azimuth=args.beams, n_elevation=args.beams, fov_azimuth=30.0, fov_elevation=30.0,
                        range_max=3.0, n_bins=135, range_min=0.3)
    plane = ('<shape type="rectangle"><transform name="to_world"><rotate x="1" angle="180"/><scale x="0.6" y="0.6"/>'
             '<translate z="2"/></transform><bsdf type="acoustic"><float name="diffuse" value="0.5"/>'
             '<float name="specular" value="0"/></bsdf></shape>')
    scene = mitsonar.load_scene('<scene version="3.0.0"><integrator type="sonar_tof"/>' + head.sensor_xml()
                                + plane + "</scene>")
    V.render_volume(scene, head, spp=1024)                                  # compile once
    t = time.perf_counter()
    fast = V.render_volume(scene, head, spp=args.spp)
    t_fast = time.perf_counter() - t
    t = time.perf_counter()
    echoes = mitsonar.render_echoes(scene, head.pulse(), elements=head.elements(), spp=args.spp)
    t_echoes = time.perf_counter() - t
    t = time.perf_counter()
    vol = V.beamform_3d(echoes, head.azimuths(), head.elevations(), head.ranges())
    t_beam = time.perf_counter() - t
    print(json.dumps({
        "elements": args.elements ** 2, "beams": args.beams ** 2, "bins": head.n_bins, "spp": args.spp,
        "threads": os.cpu_count(), "scatterers": fast.meta["n_scatterers"],
        "render_volume_s": round(t_fast, 3), "render_echoes_s": round(t_echoes, 3), "beamform_3d_s": round(t_beam, 3),
        "coherent_over_fast": round((t_echoes + t_beam) / t_fast, 1),
        "nonzero_beams_fast": int((fast.intensity.sum(axis=2) > 0).sum()),
        "nonzero_beams_coherent": int((vol.intensity.sum(axis=2) > 0).sum()),
    }, indent=1))


if __name__ == "__main__":
    main()
