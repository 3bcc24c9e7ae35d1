"""hilbertmap's estimator conventions: explicit hyper-parameters, queries that change nothing,
a printable evaluation report, the ScanLike protocol, old map files."""
from __future__ import annotations

import ast
import inspect
import json
import pathlib
import re

import numpy as np
import pytest

from hilbertmap import HilbertMap, ScanLike, metrics
from hilbertmap.scanlike import as_scan_list
from hilbertmap.surfaces import sample_grid
from hilbertmap.testing import box_mesh, box_scan, orthogonal_frames

TINY = dict(n_inducing=150, n_passes=1, random_state=0, free_density=10.0, occupied_samples=4)


@pytest.fixture(scope="module")
def scan():
    return box_scan(orthogonal_frames()[0], n_pings=30, bearing_step=12.0, seed=0, rays=100)


@pytest.fixture(scope="module")
def fitted(scan):
    return HilbertMap(**TINY).fit([scan])


def test_every_hyper_parameter_is_in_the_signature_and_documented():
    sig = inspect.signature(HilbertMap.__init__)
    names = [n for n in sig.parameters if n != "self"]
    assert len(names) > 40
    assert all(sig.parameters[n].default is not inspect.Parameter.empty for n in names)
    assert not any(p.kind is inspect.Parameter.VAR_KEYWORD for p in sig.parameters.values())
    doc = HilbertMap.__doc__
    params = doc[doc.index("Parameters\n"):doc.index("Attributes\n")]
    documented = set()
    for line in params.splitlines():
        m = re.match(r"^    (\w[\w, ]*) : ", line)
        if m:
            documented.update(n.strip() for n in m.group(1).split(","))
    assert set(names) <= documented, sorted(set(names) - documented)
    assert HilbertMap().get_params() == {n: sig.parameters[n].default for n in names}


def test_get_set_params_and_unknown_names():
    hm = HilbertMap(n_inducing=10, alpha=1e-3)
    assert hm.get_params()["alpha"] == 1e-3 and repr(hm) == "HilbertMap(n_inducing=10, alpha=0.001)"
    assert hm.set_params(alpha=0.5, n_passes=2) is hm and hm.alpha == 0.5 and hm.n_passes == 2
    assert HilbertMap(**hm.get_params()).get_params() == hm.get_params()  # clone
    with pytest.raises(ValueError, match="unknown parameter 'bogus'"):
        hm.set_params(bogus=1)
    with pytest.raises(TypeError):
        HilbertMap(bogus=1)
    with pytest.raises(TypeError):  # only n_inducing may be positional
        HilbertMap(10, "grid")


def _snapshot(hm):
    """(the attribute dict, copies of its arrays): what a query must leave as it was."""
    state = dict(vars(hm))
    arrays = {k: v.copy() for k, v in state.items() if isinstance(v, np.ndarray)}
    return state, arrays


def _unchanged(hm, snap):
    state, arrays = snap
    now = vars(hm)
    assert set(now) == set(state), set(now) ^ set(state)
    for k, v in state.items():
        assert now[k] is v, k
    for k, a in arrays.items():
        np.testing.assert_array_equal(now[k], a, err_msg=k)


def _queries(hm):
    x = np.random.default_rng(0).uniform(-4, 4, (500, 3))
    hm.decision_function(x)
    hm.predict_proba(x)
    hm.seen(x)
    hm.insonified(x, part="free")
    hm.slice("z", 0.0, resolution=0.2)
    hm.isosurface(resolution=0.2)
    hm.ridge_surface(resolution=0.2)
    hm.surface("level", grid=sample_grid(hm, 0.2))


def test_queries_do_not_change_the_estimator(fitted, tmp_path):
    snap = _snapshot(fitted)
    _queries(fitted)
    _unchanged(fitted, snap)
    fitted.save(tmp_path / "m.npz")
    loaded = HilbertMap.load(tmp_path / "m.npz")
    snap = _snapshot(loaded)
    _queries(loaded)
    _unchanged(loaded, snap)


def test_surfaces_from_a_shared_grid_equal_their_own(fitted):
    grid = sample_grid(fitted, 0.2)
    for method in ("ridge", "level"):
        V, F = fitted.surface(method, resolution=0.2)
        Vg, Fg = fitted.surface(method, grid=grid)
        np.testing.assert_array_equal(V, Vg)
        np.testing.assert_array_equal(F, Fg)


def test_evaluation_report_prints_short_and_keeps_its_arrays(fitted):
    V, F = box_mesh()
    snap = _snapshot(fitted)
    r = metrics.evaluate(fitted, V, F, n_surface=1000, n_free=5000, resolution=0.2)
    _unchanged(fitted, snap)  # scoring a map is a query too
    text = repr(r)
    assert len(text) < 2000 and str(r) == text
    assert f"auc={r['auc']:.4g}" in text and "meshes=<ridge:" in text
    assert isinstance(r["auc"], float) and r["params"]["n_inducing"] == 150
    json.dumps(r)  # numbers only
    assert set(r.meshes) == {"ridge", "level"} and r.points["surface"].shape[1] == 3
    with pytest.warns(DeprecationWarning, match="report.meshes"):
        assert r["_meshes"] is r.meshes  # the old spelling, for one release
    with pytest.warns(DeprecationWarning, match="report.points"):
        assert r["_points"] is r.points
    with pytest.raises(KeyError):
        r["nope"]


def test_scanlike_protocol(scan):
    assert isinstance(scan, ScanLike)
    assert as_scan_list(scan) == [scan]

    class NoWidths:
        def __init__(self, s):
            for a in ("data", "intensity", "poses", "ranges", "range_min", "range_max", "beamwidth_h"):
                setattr(self, a, getattr(s, a))

    with pytest.raises(TypeError, match="a scan lacks the attribute 'beamwidth_v'"):
        HilbertMap(**TINY).fit([NoWidths(scan)])


def test_hilbertmap_never_imports_mitsonar():
    """Every import of every module (also inside functions), read from the source."""
    root = pathlib.Path(__file__).resolve().parents[1] / "hilbertmap"
    for path in root.glob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else []
            assert not any(n.split(".")[0] in ("mitsonar", "mitsuba") for n in names), path.name


def test_a_map_saved_before_the_free_sample_record_still_loads(fitted, tmp_path):
    fitted.save(tmp_path / "new.npz")
    z = dict(np.load(tmp_path / "new.npz"))
    del z["free_coverage_keys"]
    np.savez_compressed(tmp_path / "old.npz", **z)
    old = HilbertMap.load(tmp_path / "old.npz")
    assert not hasattr(old, "free_coverage_")
    x = np.random.default_rng(1).uniform(-4, 4, (200, 3))
    np.testing.assert_array_equal(old.predict_proba(x), fitted.predict_proba(x))
    assert len(old.ridge_surface(resolution=0.2)[1]) > 0
