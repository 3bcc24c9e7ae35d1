"""The layout of `mitsonar.jobs.compare` (a package): its public names, the old import paths of names
that moved (they still work and warn), and an import graph without cycles inside the package."""
import ast
import os
import warnings

import pytest

from conftest import ROOT

PACKAGE = os.path.join(ROOT, "mitsonar", "jobs", "compare")


def test_public_names_import_from_the_package():
    from mitsonar.jobs.compare import (DEFAULT_REFERENCE_FACTOR, DEFAULT_REPEATS, CompareError, compare,  # noqa: F401
                                  error_metrics, jsonable, labels_for, load_integrator, plan_spp)

    assert DEFAULT_REFERENCE_FACTOR == 16.0 and DEFAULT_REPEATS == 2
    assert issubclass(CompareError, ValueError)
    import mitsonar.jobs.compare as cmp

    for name in cmp.__all__:
        assert getattr(cmp, name) is not None, name


@pytest.mark.parametrize("name", ["parse_budgets", "parse_integrators", "parse_params", "parse_regions"])
def test_moved_parsers_still_import_from_the_old_path_and_warn(name):
    import mitsonar.jobs.compare as cmp
    from mitsonar.jobs.compare import parsing

    with pytest.warns(DeprecationWarning, match=f"mitsonar.jobs.compare.parsing.{name}"):
        old = getattr(cmp, name)
    assert old is getattr(parsing, name)
    with pytest.warns(DeprecationWarning, match="moved to mitsonar.jobs.compare.parsing"):
        exec(f"from mitsonar.jobs.compare import {name}", {})
    # The new home does not warn.
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        exec(f"from mitsonar.jobs.compare.parsing import {name}", {})


def test_unknown_names_still_raise_attribute_error():
    import mitsonar.jobs.compare as cmp

    with pytest.raises(AttributeError, match="no attribute 'parse_nothing'"):
        cmp.parse_nothing  # noqa: B018


def _edges():
    """Module -> modules of mitsonar.jobs.compare it imports (every import, inside functions too; a
    submodule importing its package is an edge to the package, the package importing its own
    submodules is not)."""
    mods = {f[:-3]: os.path.join(PACKAGE, f) for f in os.listdir(PACKAGE) if f.endswith(".py")}
    edges = {}
    for mod, path in mods.items():
        edges[mod] = set()
        for node in ast.walk(ast.parse(open(path).read())):
            if isinstance(node, ast.ImportFrom) and node.level == 1:
                targets = [node.module] if node.module else [a.name for a in node.names] + ["__init__"]
            elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("mitsonar.jobs.compare"):
                rest = node.module[len("mitsonar.jobs.compare"):].lstrip(".")
                targets = [rest.split(".")[0] if rest else "__init__"]
            elif isinstance(node, ast.Import):
                targets = [a.name[len("mitsonar.jobs.compare."):].split(".")[0] for a in node.names
                           if a.name.startswith("mitsonar.jobs.compare.")]
            else:
                continue
            for t in targets:
                if t in mods and t != mod and not (mod == "__init__" and t != "__init__"):
                    edges[mod].add(t)
    return edges


def test_package_import_graph_is_acyclic_and_modules_are_small():
    edges = _edges()
    state = {}

    def visit(m, trail):
        if state.get(m) == "open":
            raise AssertionError(f"import cycle: {' -> '.join(trail + [m])}")
        if state.get(m) == "done":
            return
        state[m] = "open"
        for n in sorted(edges[m]):
            visit(n, trail + [m])
        state[m] = "done"

    for m in edges:
        visit(m, [])
    for f in os.listdir(PACKAGE):
        if f.endswith(".py"):
            with open(os.path.join(PACKAGE, f)) as fh:
                assert sum(1 for _ in fh) <= 600, f
    # The command line imports the package, never the other way round.
    assert not any("compare_cli" in open(os.path.join(PACKAGE, f)).read() for f in os.listdir(PACKAGE)
                   if f.endswith(".py"))
