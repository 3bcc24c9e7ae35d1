"""The one staged-Adam check-then-refine driver (mitsonar.inverse.driver.staged_refine) that the
room's and the piles' refinements run their models through."""
import numpy as np
import pytest


def _never(params, opt):
    raise AssertionError("the model was built before the inputs were checked")


@pytest.mark.parametrize("kwargs, words", [
    (dict(lr=0.0), "need lr > 0"),
    (dict(lr_decay=1.5), "need lr > 0 and 0 < lr_decay <= 1"),
    (dict(stages=((4.0, -1),)), "stages must be (blur_bins >= 0, iterations >= 0) pairs"),
    (dict(targets=[np.zeros((3, 4))] * 2), "one target per pose is needed, got 1 poses and 2 targets"),
])
def test_staged_refine_refuses_before_building_the_model(kwargs, words):
    from mitsonar.inverse.driver import staged_refine

    args = dict(poses=[np.eye(4)], targets=[np.zeros((3, 4))], stages=((4.0, 2),), lr=0.03, lr_decay=0.1)
    args.update(kwargs)
    with pytest.raises(ValueError, match=r"^toy: ") as e:
        staged_refine("toy", None, args.pop("poses"), args.pop("targets"), _never, head="head",
                      key="mesh.vertex_positions", spp=4, seed=0, deterministic=True, **args)
    assert words in str(e.value)


@pytest.mark.parametrize("module, call, key", [
    ("room", lambda f: f(None, [[1, -1], [1, 1], [-1, 1], [-1, -1]], -2.0, [np.eye(4)], [np.zeros((3, 4))],
                         top=5.0, stages=((4.0, 2),)), "room.vertex_positions"),
    ("piles", lambda f: f(None, [[1.0, 0.0, 0.3]], -4.0, [np.eye(4)], [np.zeros((3, 4))], top=6.0,
                          bounds=((-5, -5), (5, 5)), stages=((4.0, 2),)),
     ("piles.vertex_positions", "seabed.vertex_positions")),
])
def test_the_room_and_the_piles_run_through_the_one_driver(monkeypatch, module, call, key):
    import importlib

    mod = importlib.import_module(f"mitsonar.inverse.{module}")
    seen = {}

    def driver(what, scene, poses, targets, build, **kw):
        seen.update(what=what, key=kw["key"], stages=kw["stages"], build=build)
        return {"driven": True}

    monkeypatch.setattr(mod, "staged_refine", driver)
    assert call(getattr(mod, f"refine_{module}")) == {"driven": True}
    assert seen["what"] == f"refine_{module}" and seen["key"] == key and seen["stages"] == ((4.0, 2),)
    assert callable(seen["build"])
