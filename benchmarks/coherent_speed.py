"""Cost of coherent element data against the incoherent scan, on the box seen by a forward-looking head.

A 64-element line array at half a wavelength (``elements="line_array"``) hears one LFM frame of
``scenes_xml/box_fls.xml`` (256 receive beams, 12 m); each frame is beamformed into the head's 256
bearings x 500 bins (`mitsonar.signals.beamform`). The beamformed intensity of one frame is a speckle
realisation (exponential per bin), so its mean over speckle seeds converges as 1 / sqrt(K): the
script reports the relative L2 error of the mean of K frames against a reference of other seeds,
with the time per frame, beside `render_scan`'s time for the incoherent 256-beam frame.

    python benchmarks/coherent_speed.py [--spp 4096] [--ref 32] [--k 1,4,16]
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=4096, help="paths per coherent frame")
    ap.add_argument("--ref", type=int, default=32, help="speckle seeds of the reference")
    ap.add_argument("--k", default="1,4,16", help="seeds averaged, comma separated")
    ap.add_argument("--incoherent-spp", type=int, default=256)
    args = ap.parse_args(argv)
    import mitsonar
    from mitsonar import signals as S

    scene = mitsonar.load_scene(os.path.join(os.path.dirname(__file__), "..", "scenes_xml", "box_fls.xml"))
    pulse = S.lfm(687.5e3, 712.5e3, 1e-3)          # c / (2 B) = 3 cm; 425 samples at 25 kHz
    t = time.perf_counter()
    mitsonar.render_scan(scene, spp=args.incoherent_spp)
    t_inc = time.perf_counter() - t
    print(f"render_scan 256 beams x 500 bins, spp {args.incoherent_spp}: {t_inc:.2f} s")

    def frame(seed):
        t0 = time.perf_counter()
        e = mitsonar.render_echoes(scene, pulse, elements="line_array", spp=args.spp, seed=seed, speckle_seed=seed,
                                   sample_rate=pulse.bandwidth)
        t1 = time.perf_counter()
        scan = S.beamform(e)
        return scan.intensity.astype(np.float64), t1 - t0, time.perf_counter() - t1, e

    ref = []
    for s in range(1000, 1000 + args.ref):
        ref.append(frame(s)[0])
    ref = np.mean(ref, axis=0)
    ks = [int(k) for k in args.k.split(",")]
    acc, times = [], []
    for s in range(max(ks)):
        img, t_r, t_b, e = frame(s)
        acc.append(img)
        times.append((t_r, t_b))
        if len(acc) in ks:
            err = np.linalg.norm(np.mean(acc, axis=0) - ref) / np.linalg.norm(ref)
            print(f"K={len(acc):3d} frames: rel L2 {err:.3f} against {args.ref} other seeds")
    t_r, t_b = np.median(times, axis=0)
    print(f"per frame: render_echoes {t_r:.2f} s ({e.meta['n_scatterers']} scatterers, {e.signal.shape}), "
          f"beamform {t_b:.2f} s")


if __name__ == "__main__":
    main()
