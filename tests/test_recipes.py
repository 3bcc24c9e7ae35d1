"""The recipes of docs/developer.rst ("Where to add ..."), followed step by step: a toy sonar kind,
head, BSDF and output format, each defined here (or written to ``tmp_path``) and registered
through the house's own calls, touching no file of mitsonar; each registration is undone at the
end, so the other tests never see the toys."""
from __future__ import annotations

import importlib.util
import math
import sys
import textwrap

import numpy as np
import pytest

from test_plugins import plane_scene

C = 1500.0   # the sensor's default sound speed, m/s


def floor_scene(mitsonar, bsdf, **sonar):
    """A sonar 2 m above a 40 m floor, looking 40 deg down; one bounce (``max_depth`` 1): the plugin
    tests' floor (`test_plugins.plane_scene`) with the BSDF given."""
    return plane_scene(mitsonar, bsdf, **sonar)


LAMBERT = '<bsdf type="acoustic"><float name="diffuse" value="0.5"/><float name="specular" value="0"/></bsdf>'


# ----------------------------------------------------------------------------- a sonar kind
def test_recipe_sonar_kind(mitsonar_mod):
    """Recipe "a new sonar kind": one `SonarKind` subclass, `kinds.register`; a scene names it in
    the sensor's ``kind`` and renders. The toy fires every other ping slot of a mechanical head
    and keeps its own overhead: its rows are the mechanical head's echoes (same beams, same
    paths), at ``2 k (2 range_max / c + overhead)``."""
    import mitsonar.kinds as kinds

    class Toy(kinds.Mechanical):
        name = "toy_kind"
        head_overhead = 0.25

        def ping_times(self, ping_period, pings, n_rows):
            return 2.0 * np.arange(n_rows) * ping_period

    kinds.register(Toy)
    try:
        common = dict(n_pings=3, bearing_step=10.0)
        toy = mitsonar_mod.render_scan(floor_scene(mitsonar_mod, LAMBERT, kind="toy_kind", **common), spp=64, seed=1)
        ref = mitsonar_mod.render_scan(floor_scene(mitsonar_mod, LAMBERT, kind="mechanical", **common), spp=64, seed=1)
        assert toy.kind == "toy_kind" and isinstance(toy.sonar_kind, Toy)
        np.testing.assert_allclose(toy.times, 2 * np.arange(3) * (2 * 5.0 / C + 0.25), rtol=1e-12)
        np.testing.assert_allclose(ref.times, np.arange(3) * (2 * 5.0 / C + 0.030), rtol=1e-12)
        assert toy.intensity.sum() > 0
        # the same paths: equal bit for bit on the CPU (a GPU may round two kernels differently)
        np.testing.assert_allclose(toy.intensity, ref.intensity, rtol=1e-6, atol=0)
        np.testing.assert_array_equal(toy.bearings, ref.bearings)
    finally:
        kinds.unregister("toy_kind")
    assert "toy_kind" not in kinds.names()


# ----------------------------------------------------------------------------- a head
def test_recipe_head(capsys, tmp_path):
    """Recipe "a new head": a `Head` subclass instance, `registry.register`; it is then a
    ``--head`` choice, `registry.get` and `registry.for_log` answer it as they answer the built-in
    heads, and the command line refuses another head's option for it in the same words.
    (tests/test_head_registry.py serves, records and replays a full toy head this way.)"""
    from mitsonar.cli.main import main
    from mitsonar.devices import registry
    from mitsonar.devices.head import Head

    class ToyHead(Head):
        name = "toy_recipe"
        description = "a head of the recipes' test"
        log_tag = "toy-recipe"
        protocol = "none"
        packet = "none"
        ping_word = "pings"
        serves = "nothing"

    head = registry.register(ToyHead())
    try:
        assert registry.get("toy_recipe") is head and registry.names()[-1] == "toy_recipe"
        assert registry.for_log({"head": "toy-recipe"}) is head
        assert registry.for_log({"head": "ping360"}) is registry.get("ping360")
        assert head in registry.heads()
        out = tmp_path / "x.bin"
        assert main(["record", "/dev/null", "--head", "toy_recipe", "-o", str(out), "--gain", "high"]) == 1
        assert capsys.readouterr().err.strip() == "mitsonar record: error: --gain is for --head ping360, not toy_recipe"
        assert not out.exists()
    finally:
        registry.unregister("toy_recipe")
    assert "toy_recipe" not in registry.names()
    with pytest.raises(ValueError, match="unknown head 'toy_recipe'"):
        registry.get("toy_recipe")


# ----------------------------------------------------------------------------- a BSDF
TOY_BSDF = '''
"""The ``recipe_constant`` BSDF: a constant BRDF, f = brdf (1/sr) in every direction."""
import drjit as dr
import mitsuba as mi

from mitsonar._checks import not_allowed
from mitsonar.plugins.props import number
from mitsonar.plugins.registry import register_plugin


class ConstantBSDF(mi.BSDF):
    """A constant BRDF.

    ========= ======= ==========================================
    Parameter Default Meaning
    ========= ======= ==========================================
    brdf      0.1     the BRDF's value, 1/sr (0 .. 1/pi)
    ========= ======= ==========================================
    """

    def __init__(self, props):
        super().__init__(props)
        value = number(props, "brdf", 0.1, "recipe_constant", "a <float> in [0, 1/pi]")
        if not 0 <= value <= 1 / dr.pi:
            raise not_allowed("recipe_constant", "brdf", value, "must be in [0, 1/pi]")
        self.brdf = dr.opaque(mi.Float, value)
        self.m_components = [mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide]
        self.m_flags = self.m_components[0]

    def _cosines(self, si, wo):
        cos_o = mi.Frame3f.cos_theta(wo)
        return cos_o, (mi.Frame3f.cos_theta(si.wi) > 0) & (cos_o > 0)

    def eval(self, ctx, si, wo, active=True):
        cos_o, ok = self._cosines(si, wo)
        return mi.Spectrum(dr.select(active & ok, self.brdf * cos_o, 0.0))

    def pdf(self, ctx, si, wo, active=True):
        cos_o, ok = self._cosines(si, wo)
        return dr.select(active & ok, cos_o * dr.inv_pi, 0.0)

    def eval_pdf(self, ctx, si, wo, active=True):
        return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

    def sample(self, ctx, si, sample1, sample2, active=True):
        bs = mi.BSDFSample3f()
        bs.wo = mi.warp.square_to_cosine_hemisphere(sample2)
        bs.pdf = mi.warp.square_to_cosine_hemisphere_pdf(bs.wo)
        bs.eta = 1.0
        bs.sampled_type = mi.UInt32(+mi.BSDFFlags.DiffuseReflection)
        bs.sampled_component = mi.UInt32(0)
        ok = active & (mi.Frame3f.cos_theta(si.wi) > 0) & (bs.pdf > 0)
        return bs, mi.Spectrum(dr.select(ok, self.brdf * dr.pi, 0.0))

    def traverse(self, callback):
        callback.put("brdf", self.brdf, mi.ParamFlags.Differentiable)

    def to_string(self):
        return f"ConstantBSDF[brdf={self.brdf[0]:g}]"


register_plugin("BSDF", "recipe_constant", ConstantBSDF)
'''


def test_recipe_bsdf(mitsonar_mod, tmp_path):
    """Recipe "a new BSDF": one module (here written to ``tmp_path``, in the recipe
    ``plugins/bsdfs/<name>.py``) whose class reads its parameters from its docstring table and which
    ends with ``register_plugin("BSDF", ...)``; importing it for the variant registers it. Its echo
    follows its formula: a constant BRDF ``k`` is a Lambert surface of albedo ``pi k``, so it
    echoes exactly as ``acoustic`` with ``diffuse = pi k`` and no specular lobe, and twice ``k``
    echoes twice as loud (one bounce)."""
    from mitsonar import plugins
    from mitsonar.sim.variant import ensure_variant

    ensure_variant()
    path = tmp_path / "recipe_constant.py"
    path.write_text(textwrap.dedent(TOY_BSDF))
    spec = importlib.util.spec_from_file_location("recipe_constant", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules["recipe_constant"] = module
    try:
        spec.loader.exec_module(module)
        assert plugins.registered()["recipe_constant"] == ("BSDF", module.ConstantBSDF)
        assert plugins.parameters(module.ConstantBSDF) == ["brdf"]

        def echo(bsdf):
            return mitsonar_mod.render_scan(floor_scene(mitsonar_mod, bsdf), spp=4096, seed=5).intensity[0]

        k = 0.1
        toy = echo(f'<bsdf type="recipe_constant"><float name="brdf" value="{k}"/></bsdf>')
        twice = echo(f'<bsdf type="recipe_constant"><float name="brdf" value="{2 * k}"/></bsdf>')
        lambert = echo(f'<bsdf type="acoustic"><float name="diffuse" value="{math.pi * k!r}"/>'
                       '<float name="specular" value="0"/></bsdf>')
        lit = lambert > 1e-3 * lambert.max()
        assert lit.sum() >= 10
        np.testing.assert_allclose(toy[lit], lambert[lit], rtol=1e-4)
        np.testing.assert_allclose(twice[lit], 2 * toy[lit], rtol=1e-4)
        assert np.all(toy[~lit] <= 1e-3 * lambert.max())
        # its parameters are checked like every plugin's: an unknown name, a bad value
        with pytest.raises(mitsonar_mod.SceneError, match='"recipe_constant" has no parameter "brfd"'):
            floor_scene(mitsonar_mod, '<bsdf type="recipe_constant"><float name="brfd" value="0.1"/></bsdf>')
        with pytest.raises(mitsonar_mod.SceneError, match="brdf"):
            floor_scene(mitsonar_mod, '<bsdf type="recipe_constant"><float name="brdf" value="0.5"/></bsdf>')
    finally:
        plugins.unregister_plugin("recipe_constant")
        sys.modules.pop("recipe_constant", None)
    assert "recipe_constant" not in plugins.registered()


# ----------------------------------------------------------------------------- an output format
class ToyFormatError(ValueError):
    pass


def check_toy_output(path, force=False):
    """Step 2 of the recipe: the output refused in one line before any work (`check_output_file`)."""
    from mitsonar._files import check_output_file

    return check_output_file(path, ToyFormatError, extensions=(".toy",), force=force)


def write_toy(path, scans) -> int:
    """Step 3: every scan checked first, then the file written under a temporary name (`replacing`):
    per scan one text line ``n_rows n_bins range_min range_max`` and its data rows as hex."""
    from mitsonar._files import replacing

    for i, scan in enumerate(scans):
        if np.asarray(scan.data).dtype != np.uint8:
            raise ToyFormatError(f"scans[{i}]: 'data' is {scan.data.dtype}; allowed: uint8")
    with replacing(path) as tmp, open(tmp, "w", encoding="ascii") as f:
        for scan in scans:
            f.write(f"{scan.data.shape[0]} {scan.data.shape[1]} {float(scan.range_min).hex()} "
                    f"{float(scan.range_max).hex()}\n")
            for row in np.asarray(scan.data):
                f.write(row.tobytes().hex() + "\n")
    return len(scans)


def read_toy(path) -> list:
    lines = open(path, encoding="ascii").read().splitlines()
    out = []
    while lines:
        rows, bins, lo, hi = lines.pop(0).split()
        data = np.array([np.frombuffer(bytes.fromhex(lines.pop(0)), np.uint8) for _ in range(int(rows))])
        assert data.shape == (int(rows), int(bins))
        out.append((data, float.fromhex(lo), float.fromhex(hi)))
    return out


def test_recipe_output_format(mitsonar_mod, tmp_path):
    """Recipe "a new output format": no registry (each format is its own module and flag); a
    module of ``mitsonar/export/`` with a check of the output and a writer through the shared file
    helpers. The toy writes two scans and reads them back byte for byte; a bad output or a bad
    scan is refused in one line and leaves no file."""
    scan = mitsonar_mod.render_scan(floor_scene(mitsonar_mod, LAMBERT, n_pings=2, bearing_step=5.0), spp=16, seed=0)
    other = mitsonar_mod.Scan(intensity=scan.intensity[::-1].copy(), data=scan.data[::-1].copy(),
                              ranges=scan.ranges, bearings=scan.bearings, poses=scan.poses,
                              range_min=scan.range_min, range_max=scan.range_max)
    out = tmp_path / "two.toy"
    assert check_toy_output(out) == str(out)
    assert write_toy(out, [scan, other]) == 2
    back = read_toy(out)
    assert [(d.tobytes(), lo, hi) for d, lo, hi in back] == [
        (s.data.tobytes(), s.range_min, s.range_max) for s in (scan, other)]
    assert scan.data.any()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["two.toy"]
    with pytest.raises(ToyFormatError, match=r"^.*two\.toy: exists; refusing to overwrite it \(use --force\)$"):
        check_toy_output(out)
    with pytest.raises(ToyFormatError, match=r"unknown extension '\.txt'; use \.toy"):
        check_toy_output(tmp_path / "a.txt")
    wide = mitsonar_mod.Scan(intensity=scan.intensity, data=scan.data.astype(np.uint16), ranges=scan.ranges,
                             bearings=scan.bearings, poses=scan.poses, range_min=scan.range_min,
                             range_max=scan.range_max)
    with pytest.raises(ToyFormatError, match=r"^scans\[1\]: 'data' is uint16; allowed: uint8$"):
        write_toy(tmp_path / "bad.toy", [scan, wide])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["two.toy"]
