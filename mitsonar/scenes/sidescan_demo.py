"""The side-scan demo: a lawnmower survey over the wreck (``scenes_xml/wreck_sidescan.xml`` along
``wreck_sidescan_survey.tum``), its waterfall and its georeferenced mosaic.

``python -m mitsonar.scenes.sidescan_demo -o out`` (``scripts/demo.sh`` runs it) writes
``wreck_sidescan_waterfall.png`` (the scan passing the wreck on the first line, slant range),
``wreck_sidescan_waterfall_ground.png`` (the same, ground range over a flat bottom at the
measured altitude), ``wreck_sidescan_mosaic.png`` with ``.pgw`` and ``.npz`` (the bare
georeferenced mosaic and its array + affine transform) and ``wreck_sidescan_mosaic_map.png``
(the mosaic with axes, the track and the wreck's outline).
"""
from __future__ import annotations

import argparse
import os
import sys

SCENE, TRACK = "wreck_sidescan.xml", "wreck_sidescan_survey.tum"
# the wreck's parts (not the seabed) drawn over the mosaic
WRECK_SHAPES = ("hull", "bow", "deckhouse", "mast")


def demo_sidescan(scenes, output, spp=64, seed=0, resolution=0.05, quiet=True) -> list:
    """Render the side-scan survey of the wreck and write its pictures into ``output`` (created);
    returns the files written."""
    import numpy as np

    import mitsonar

    from mitsonar.products.mosaic import MosaicBuilder
    from mitsonar.products.sidescan_plots import plot_mosaic, plot_waterfall

    scene = mitsonar.load_scene(os.path.join(scenes, SCENE))
    track = mitsonar.Trajectory.from_tum(os.path.join(scenes, TRACK))
    os.makedirs(output, exist_ok=True)
    builder = MosaicBuilder((-12.0, 12.0, -8.0, 8.0), resolution, use="data")
    written, abeam = [], None
    for scan in mitsonar.render_survey(scene, track, spp=spp, seed=seed, progress=not quiet):
        builder.add(scan)
        x = scan.positions[:, 0]
        if abeam is None and x.min() <= 0.0 <= x.max():   # the first scan passing the hull's middle
            abeam = scan
    for ground in (False, True):
        written.append(os.path.join(output, "wreck_sidescan_waterfall" + ("_ground" if ground else "") + ".png"))
        plot_waterfall(abeam, written[-1], ground=ground)
    m = builder.result()
    written += m.save(os.path.join(output, "wreck_sidescan_mosaic.png"))
    v, f = mitsonar.scene_mesh(mitsonar.load_scene(_objects_only(scenes)))
    written.append(os.path.join(output, "wreck_sidescan_mosaic_map.png"))
    plot_mosaic(m, written[-1], mesh=(v, f), track=track)
    assert np.isfinite(m.image).any()
    return written


def _objects_only(scenes) -> str:
    """The wreck scene's XML without its seabed (to outline the wreck's parts over the mosaic)."""
    import re

    with open(os.path.join(scenes, SCENE), encoding="utf-8") as fh:
        xml = fh.read()
    xml = re.sub(r'<shape type="ply" id="seabed">.*?</shape>', "", xml, flags=re.S)
    return xml.replace('value="wreck_seabed.ply"', "")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m mitsonar.scenes.sidescan_demo", description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", default="out", help="output folder (default out)")
    ap.add_argument("--scenes", default=None, help="the scenes_xml folder (default: the repository's)")
    ap.add_argument("--spp", type=int, default=64, help="paths per ping and channel (default 64)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("-q", "--quiet", action="store_true")
    args = ap.parse_args(argv)
    package = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    scenes = args.scenes or os.path.join(os.path.dirname(package), "scenes_xml")
    if not os.path.isfile(os.path.join(scenes, SCENE)):
        print(f"sidescan demo: {os.path.join(scenes, SCENE)} not found (give --scenes)", file=sys.stderr)
        return 2
    files = demo_sidescan(scenes, args.output, args.spp, args.seed, quiet=args.quiet)
    print(f"side-scan survey of the wreck: wrote {', '.join(files)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
