"""The packages of mitsonar form a chain: no loop between them, counting every import, those inside
functions too (issue 57: a `Scan` that imported the renderer tied eight rooms into one loop).

The graph is `scripts/package_graph.py` `import_graph` (an ast walk of every module: each Import and
ImportFrom node, at module level, inside functions, inside ``if TYPE_CHECKING``) folded onto the
packages: ``mitsonar.<room>`` (a folder; its subfolders belong to it), ``mitsonar.plugins``,
``hilbertmap``, and each module of mitsonar's own folder (``mitsonar._checks``, ...) on its own.

No loop is allowed: `test_no_loop_between_packages` names the imports that close one (issue 57:
the ray diagram moved to the pictures, the Dr.Jit backend to a room below every other, the
depth-grid and point-cloud writers to the formats' room, export, which imports products and
signals, never the reverse).
"""
import os
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scripts"))
from package_graph import cycles, module_edges, package, package_graph  # noqa: E402  (the graph's one home: scripts/package_graph.py)


def test_folding_counts_imports_inside_functions():
    """The checker: an import inside a function is an edge of its package, and a loop of packages
    made of such imports is found."""
    edges = {"mitsonar.scan.model": {"mitsonar.sim.render"}, "mitsonar.sim.render": {"mitsonar.scan"},
             "mitsonar.scan": set(), "mitsonar._checks": set()}
    graph = package_graph(edges)
    assert graph["mitsonar.scan"] == {"mitsonar.sim"} and graph["mitsonar.sim"] == {"mitsonar.scan"}
    assert cycles(graph) == [["mitsonar.scan", "mitsonar.sim"]]
    # on the real graph: the report renders a scene inside a function
    assert "mitsonar.sim" in package_graph()["mitsonar.sonar_equation"]


def loop_edges(loop, edges=None) -> list:
    """The module imports ``"a -> b"`` between two packages of ``loop`` (a list of packages): the
    imports to move to break it."""
    if edges is None:
        edges = module_edges()
    return sorted(f"{s} -> {t}" for s, ts in edges.items() for t in ts
                  if package(s) != package(t) and package(s) in loop and package(t) in loop)


def test_the_report_names_the_imports_that_close_a_loop():
    edges = {"mitsonar.scan.model": {"mitsonar.sim.render", "mitsonar.scan.meta"}, "mitsonar.scan.meta": set(),
             "mitsonar.sim.render": {"mitsonar.scan", "mitsonar._checks"}, "mitsonar.scan": set(),
             "mitsonar._checks": set()}
    assert loop_edges(["mitsonar.scan", "mitsonar.sim"], edges) == \
        ["mitsonar.scan.model -> mitsonar.sim.render", "mitsonar.sim.render -> mitsonar.scan"]


def test_no_loop_between_packages():
    """Strict: any loop of packages fails, with the imports that close it."""
    loops = cycles(package_graph())
    assert loops == [], "loops between packages, closed by: " + "; ".join(", ".join(loop_edges(c)) for c in loops)
