"""The import graph of mitsonar, its plugins and hilbertmap, built from the source: acyclic, with
hilbertmap independent of mitsonar, and no module over 700 lines (issue "Architecture").

Every import counts as an edge: at module level, inside functions, inside a module ``__getattr__``
and under ``if TYPE_CHECKING``; ``from . import x`` and ``from .x import y`` inside a package's
submodule also import the package itself (Python runs its ``__init__`` first), so they are edges
to it. A package's ``__init__`` importing its own submodules is not an edge (it gathers them).
"""
import ast
import os

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# source folder -> the name it installs as (pyproject's package-dir)
PACKAGES = {"mitsonar": "mitsonar", "plugins": "mitsonar.plugins", "hilbertmap": "hilbertmap"}
MAX_LINES = 700


def modules():
    """{module name: file path} for every .py file of the three packages."""
    out = {}
    for folder, name in PACKAGES.items():
        for root, _, files in os.walk(os.path.join(ROOT, folder)):
            for f in files:
                if f.endswith(".py"):
                    rel = os.path.relpath(os.path.join(root, f), os.path.join(ROOT, folder))[:-3]
                    parts = [name] + [p for p in rel.split(os.sep) if p != "__init__"]
                    out[".".join(parts)] = os.path.join(root, f)
    return out


def targets(module, is_package, node):
    """The modules one import statement names (longest names first are resolved by the caller)."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names]
    if node.level:
        base = module.split(".") if is_package else module.split(".")[:-1]
        base = base[: len(base) - (node.level - 1)]
        stem = ".".join(base + ([node.module] if node.module else []))
    else:
        stem = node.module
    return [f"{stem}.{a.name}" for a in node.names] + [stem]


def import_graph():
    mods = modules()
    edges = {m: set() for m in mods}
    for name, path in mods.items():
        is_package = path.endswith("__init__.py")
        with open(path, encoding="utf-8") as fh:
            tree = ast.parse(fh.read(), path)
        for node in ast.walk(tree):
            if not isinstance(node, (ast.Import, ast.ImportFrom)):
                continue
            for target in targets(name, is_package, node):
                # the nearest enclosing module we own (``from .x import y``: y may be a name in x)
                while target and target not in mods:
                    target = target.rpartition(".")[0]
                if target and target != name and not (is_package and target.startswith(name + ".")):
                    edges[name].add(target)
    return mods, edges


def cycles(edges):
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def test_the_graph_sees_lazy_imports():
    """The checker itself: imports inside functions and a module __getattr__ are edges."""
    mods, edges = import_graph()
    # render.py imports the plugins inside functions only
    assert "mitsonar.plugins" in edges["mitsonar.sim.render"]
    # a submodule importing a sibling through its package (``from mitsonar.scan import fileformat``)
    # imports both
    assert {"mitsonar.scan", "mitsonar.scan.fileformat"} <= edges["mitsonar.scan.model"]
    assert cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == [["a", "b", "c"]]


def test_import_graph_is_acyclic():
    _, edges = import_graph()
    assert cycles(edges) == []


def test_hilbertmap_does_not_import_mitsonar():
    _, edges = import_graph()
    for name, out in edges.items():
        if name.startswith("hilbertmap"):
            assert not [t for t in out if t.startswith("mitsonar")], (name, out)


@pytest.mark.parametrize("name, path", sorted(modules().items()))
def test_no_module_is_over_700_lines(name, path):
    with open(path, encoding="utf-8") as fh:
        n = sum(1 for _ in fh)
    assert n <= MAX_LINES, f"{name} has {n} lines"


def test_submodules_take_only_submodules_from_their_package():
    """``from . import __version__`` (or ``from mitsonar import load_scan``) inside mitsonar makes a
    submodule depend on the package's ``__init__``, which imports the submodules: a cycle the graph
    above cannot show, since a package gathering its submodules is no edge. Only submodules may
    be imported from one's own package."""
    mods = modules()
    bad = []
    for name, path in mods.items():
        if path.endswith("__init__.py"):
            continue
        package = name.rpartition(".")[0]
        with open(path, encoding="utf-8") as fh:
            tree = ast.parse(fh.read(), path)
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                base = targets(name, False, node)[-1]
                if base in mods and mods[base].endswith("__init__.py") and name.startswith(base + "."):
                    bad += [(name, a.name) for a in node.names if f"{base}.{a.name}" not in mods]
    assert bad == []


def test_the_plugins_use_only_the_lowest_mitsonar_modules():
    """Data flows scene -> paths -> histogram -> electronics -> Scan -> files, maps, devices: the
    plugins (paths and histograms) may use mitsonar's helpers below them (value checks, frames)
    and the electronics' settings (the sensor reads and checks its electronics fields), nothing
    else of mitsonar (not the Scan, files, render or devices)."""
    _, edges = import_graph()
    # (and the sound-speed profile: the integrators read their XML sound_speed_profile with it)
    allowed = {"mitsonar._checks", "mitsonar.geometry.frames", "mitsonar.receiver.electronics",
               "mitsonar.acoustics.profile"}
    for name, out in edges.items():
        if name.startswith("mitsonar.plugins"):
            above = {t for t in out if t.startswith("mitsonar") and not t.startswith("mitsonar.plugins")}
            assert above <= allowed, (name, above - allowed)
    # and those import nothing of mitsonar's above them (the electronics' scene speckle and the
    # sonar equation's levels are numpy-only leaves beside them)
    leaves = {"mitsonar._checks", "mitsonar.receiver.speckle", "mitsonar.sonar_equation.levels",
              "mitsonar.acoustics.seawater", "mitsonar.acoustics._checks"}
    for low in allowed | leaves - {"mitsonar._checks"}:
        assert not {t for t in edges[low] if t.startswith("mitsonar")} - leaves, low
    assert not {t for t in edges["mitsonar.receiver.speckle"] if t.startswith("mitsonar")}


def test_mitsonar_itself_holds_at_most_12_modules():
    """Code lives in packages by role (sim, scan, receiver, geometry, scenes, products, export,
    devices, jobs, cli, ...): the package's own folder keeps only its entry points and shared
    helpers, so a newcomer finds a kind, a head or a format by its room."""
    top = sorted(f for f in os.listdir(os.path.join(ROOT, "mitsonar")) if f.endswith(".py"))
    assert len(top) <= 12, top


def test_every_subpackage_says_what_it_holds():
    """Each room has a docstring saying its role (what `help()` and the API reference show)."""
    for root, _, files in os.walk(os.path.join(ROOT, "mitsonar")):
        if "__init__.py" in files:
            with open(os.path.join(root, "__init__.py"), encoding="utf-8") as fh:
                assert ast.get_docstring(ast.parse(fh.read())), root
