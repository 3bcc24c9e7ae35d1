"""The packages of mitsonar form a chain: no loop between them, counting every import, those inside
functions too (issue 57: a `Scan` that imported the renderer tied eight rooms into one loop).

The graph is `test_architecture.import_graph` (an ast walk of every module: each Import and
ImportFrom node, at module level, inside functions, inside ``if TYPE_CHECKING``) folded onto the
packages: ``mitsonar.<room>`` (a folder; its subfolders belong to it), ``mitsonar.plugins``,
``hilbertmap``, and each module of mitsonar's own folder (``mitsonar._checks``, ...) on its own.

The loops that remain belong to other rooms: `KNOWN_LOOPS` names them, and may only shrink. A loop
outside them fails the test; a room in them that has left its loop must be taken off the list.
"""
import os
import sys

import pytest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scripts"))
from package_graph import cycles, package_graph  # noqa: E402  (the graph's one home: scripts/package_graph.py)

#: The package loops left to their rooms (issue 57 items 2 and 5), as strongly connected components.
#: Imports that close them (November 2026): acoustics.raydiagram -> products.plots (pictures in
#: the acoustics room), receiver.devicechain -> sim.backend, products.soundings -> export.geotiff
#: while export.xtf -> products.sidescan, signals.volumetric -> export.las while
#: export.ros.bag -> signals.volumetric, products.bathymetry -> sim.scene, signals.echoes ->
#: sim.render and signals.focusing -> plugins.jit_arrays (with sim -> plugins -> receiver, acoustics).
KNOWN_LOOPS = [
    frozenset({"mitsonar.acoustics", "mitsonar.export", "mitsonar.plugins", "mitsonar.products",
               "mitsonar.receiver", "mitsonar.signals", "mitsonar.sim"}),
]

#: Rooms that must never be in a loop: the Scan is data, the sonar equation sits above it.
NEVER_IN_A_LOOP = ("mitsonar.scan", "mitsonar.sonar_equation")


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


def test_no_new_loop_between_packages():
    loops = [frozenset(c) for c in cycles(package_graph())]
    new = [sorted(c) for c in loops if not any(c <= known for known in KNOWN_LOOPS)]
    assert new == [], f"a loop between packages that KNOWN_LOOPS does not allow: {new}"


@pytest.mark.parametrize("room", NEVER_IN_A_LOOP)
def test_scan_and_sonar_equation_are_in_no_loop(room):
    assert not [c for c in cycles(package_graph()) if room in c]


def test_the_known_loops_are_still_loops():
    """The allowance only shrinks: a room that left its loop comes off `KNOWN_LOOPS`."""
    graph = package_graph()
    looping = set().union(*map(set, cycles(graph)))
    gone = sorted(set().union(*KNOWN_LOOPS) - looping)
    assert gone == [], f"no longer in a loop: take {gone} off KNOWN_LOOPS"
