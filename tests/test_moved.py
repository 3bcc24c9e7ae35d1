"""The old paths of moved public modules (`mitsonar._moved.MOVED`): each is a small module that
re-exports its new home's names and warns with the new path and the release that removes it."""
import ast
import importlib
import os
import sys
import warnings

import pytest

from mitsonar._moved import MOVED

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _path(module):
    return os.path.join(ROOT, *module.split(".")) + ".py"


@pytest.mark.parametrize("old", sorted(MOVED))
def test_an_old_path_warns_and_reexports(old):
    new, removal = MOVED[old]
    sys.modules.pop(old, None)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mod = importlib.import_module(old)
    messages = [str(w.message) for w in caught if issubclass(w.category, DeprecationWarning)]
    assert messages == [f"{old} moved to {new}; the old path is removed in mitsonar {removal}"]
    target = importlib.import_module(new)
    names = getattr(target, "__all__", None) or [n for n in vars(target) if not n.startswith("_")]
    assert names and all(getattr(mod, n) is getattr(target, n) for n in names)


@pytest.mark.parametrize("old", sorted(MOVED))
def test_an_old_path_is_only_a_forward(old):
    """Three statements besides the docstring: import `warn`, re-export the new home, warn."""
    with open(_path(old), encoding="utf-8") as fh:
        tree = ast.parse(fh.read())
    body = tree.body[1:] if ast.get_docstring(tree) else tree.body
    assert len(body) <= 4, old
    assert all(isinstance(n, (ast.ImportFrom, ast.Expr)) for n in body), old
