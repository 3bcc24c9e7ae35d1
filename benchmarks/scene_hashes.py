"""Byte guard for refactors: SHA-256 of every shipped scene's rendered scan.

Renders each scene of ``scenes_xml/`` (every sensor it holds: mechanical, multibeam, side-scan,
forward-looking arrays), each echo-sounder preset of `mitsonar.scenes.echosounders` over a
flat seabed, and ``box``/``box_fls`` with every beam pattern (receive ``sinc``, ``uniform``,
``table``; transmit ``sinc``, ``uniform``), at a small fixed ``spp`` and ``seed``, and prints one JSON object mapping
``<scene>[<sensor>]`` to the SHA-256 of ``scan.intensity`` and of ``scan.data``. A change meant to
leave behaviour alone must leave this output identical::

    python benchmarks/scene_hashes.py > before.json
    # ... change ...
    python benchmarks/scene_hashes.py > after.json && cmp before.json after.json

Options: ``--spp`` (default 32), ``--seed`` (default 3), ``--only`` (substring of the names).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import os
import sys
import tempfile
import warnings

import numpy as np

FLOOR = """<scene version="3.0.0">
  <integrator type="sonar_tof"><integer name="max_depth" value="2"/></integrator>
  {sensor}
  <shape type="rectangle">
    <transform name="to_world"><scale x="200" y="200"/><translate z="-30"/></transform>
    <bsdf type="acoustic"><float name="diffuse" value="0.3"/></bsdf>
  </shape>
</scene>"""


def _digest(a) -> str:
    a = np.ascontiguousarray(a)
    h = hashlib.sha256()
    h.update(str((a.dtype.str, a.shape)).encode())
    h.update(a.tobytes())
    return h.hexdigest()


def scenes():
    """(name, a callable giving the loaded scene) for every scene the guard renders."""
    import mitsonar
    from mitsonar.scenes import echosounders

    out = [(name, (lambda n=name: mitsonar.load_scene(mitsonar.example_scene(n)))) for name in mitsonar.example_scenes()]
    for preset in sorted(echosounders.PRESETS):
        def load(p=preset):
            head = echosounders.configure(p, range_max=40.0)
            return mitsonar.load_scene(FLOOR.format(sensor=echosounders.sonar_xml(head)))
        out.append((f"echosounder:{preset}", load))
    table = os.path.join(tempfile.mkdtemp(prefix="scene_hashes_"), "beam.csv")
    with open(table, "w") as fh:
        fh.write("axis,angle_deg,gain_db\n" + "".join(f"{a},{ang},{g}\n" for a, pts in (
            ("h", ((-6, -30), (-2, -6), (0, 0), (1.5, -3), (5, -25))),
            ("v", ((-30, -20), (0, 0), (20, -6), (40, -30)))) for ang, g in pts))
    rx = '<string name="beam_pattern" value="gaussian"/>'
    for base, pattern, tx in (("box", "sinc", None), ("box", "uniform", None), ("box", "table", None),
                              ("box_fls", "sinc", "sinc"), ("box_fls", "gaussian", "uniform")):
        extra = (f'<string name="beam_table" value="{table}"/>' if pattern == "table" else
                 f'<string name="tx_pattern" value="{tx}"/>' if tx else "")
        def load(b=base, p=pattern, e=extra):
            path = mitsonar.example_scene(b)
            xml = open(path, encoding="utf-8").read()
            assert rx in xml, (b, "no gaussian receive pattern to replace")
            xml = xml.replace(rx, f'<string name="beam_pattern" value="{p}"/>{e}')
            return mitsonar.load_scene(xml)
        out.append((f"{base}:{pattern}" + (f":tx_{tx}" if tx else ""), load))
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=32)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--only", default="")
    args = ap.parse_args(argv)
    import mitsonar

    warnings.simplefilter("ignore", UserWarning)   # "has 2 sonar sensors": each is rendered
    result = {}
    for name, load in scenes():
        if args.only not in name:
            continue
        scene = load()
        for k in range(len(scene.sensors())):
            scan = mitsonar.render_scan(scene, spp=args.spp, seed=args.seed, sensor=k)
            result[f"{name}[{k}]"] = {"intensity": _digest(scan.intensity), "data": _digest(scan.data)}
            print(name, k, file=sys.stderr, flush=True)
    json.dump(result, sys.stdout, indent=1, sort_keys=True)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
