"""Sphinx directive ``.. mitsonar-package-graph::``: the import graph of mitsonar's packages, drawn
at build time from the source, as an SVG embedded in the page.

The graph is the one the tests check (``scripts/package_graph.py``: `package_graph` over
`import_graph`, every import counted, those inside functions too), laid out in rows by `layers`
(each package above every package it imports; the packages of a loop share a row) and drawn with
Matplotlib (no Graphviz), with the text kept as text and no date or random id in the file: the
same source gives the same bytes.
"""
from __future__ import annotations

import io
import os
import re
import sys

from docutils import nodes
from sphinx.util.docutils import SphinxDirective

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "scripts"))

import package_graph as pg  # noqa: E402  (scripts/package_graph.py, the tests' graph)

#: box colours: a room (folder) of mitsonar, a module of mitsonar's own folder, another package
FILL = {"room": "#dbe9f6", "module": "#f3f3f3", "package": "#e4f2dc"}
LOOP = "#c0392b"


def label(name: str) -> str:
    """What a package is called on the picture: ``sim/`` (a folder of mitsonar), ``kinds.py`` (a
    module of its own folder; ``__init__.py`` is the package ``mitsonar`` itself), ``plugins/``,
    ``hilbertmap/``."""
    if name == "mitsonar":
        return "__init__.py"
    if name == "mitsonar.plugins":
        return "plugins/"
    if not name.startswith("mitsonar."):
        return f"{name}/"
    leaf = name.split(".", 1)[1]
    return f"{leaf}/" if os.path.isdir(os.path.join(ROOT, "mitsonar", leaf)) else f"{leaf}.py"


def _kind(name: str) -> str:
    if name.startswith("mitsonar.") and name != "mitsonar.plugins":
        return "room" if label(name).endswith("/") else "module"
    return "package"


def draw(graph: dict, fmt: str = "svg"):
    """The SVG text of ``graph`` ({package: set of packages it imports}): one box per package in
    the rows of `package_graph.layers` (bottom row: imports none of the others), one arrow per
    import from the importer down to what it imports; the imports inside a loop in red.
    ``fmt="png"`` gives PNG bytes instead, to look at the picture outside the docs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

    rows = pg.layers(graph)
    loops = {p for c in pg.cycles(graph) for p in c}
    wide = max(len(r) for r in rows)
    box_w = 0.2 + 0.09 * max(len(label(p)) for p in graph)      # inches: monospace 10 pt labels
    box_h, gap_x, gap_y = 0.34, 0.25, 0.95
    width = wide * (box_w + gap_x)
    where = {}
    for k, row in enumerate(rows):
        step = width / len(row)
        for i, p in enumerate(row):
            where[p] = ((i + 0.5) * step, k * gap_y)
    height = (len(rows) - 1) * gap_y
    with matplotlib.rc_context({"svg.hashsalt": "mitsonar-package-graph", "svg.fonttype": "none",
                                "font.family": "DejaVu Sans", "font.size": 10}):
        fig = plt.figure(figsize=(width, height + 1.3))
        ax = fig.add_axes([0, 0, 1, 1])
        ax.set_xlim(0, width)
        ax.set_ylim(-0.75, height + 0.55)
        ax.axis("off")
        for a in sorted(graph):
            for b in sorted(graph[a]):
                (xa, ya), (xb, yb) = where[a], where[b]
                sideways = ya == yb
                start = (xa, ya) if sideways else (xa, ya - box_h / 2)
                end = (xb, yb) if sideways else (xb, yb + box_h / 2)
                inside = a in loops and b in loops and sideways
                ax.add_patch(FancyArrowPatch(
                    start, end, arrowstyle="-|>", mutation_scale=7, lw=0.9 if inside else 0.5,
                    color=LOOP if inside else "#6b6b6b", alpha=0.9 if inside else 0.45,
                    # a sideways arrow bends about 0.35 in off its row (half the control offset), whatever its length
                    connectionstyle=f"arc3,rad={0.7 / abs(xb - xa):.4f}" if sideways else "arc3,rad=0.0",
                    shrinkA=9 if sideways else 0, shrinkB=9 if sideways else 0, zorder=1))
        for p, (x, y) in sorted(where.items()):
            ax.add_patch(FancyBboxPatch((x - box_w / 2, y - box_h / 2), box_w, box_h,
                                        boxstyle="round,pad=0.0,rounding_size=0.06", fc=FILL[_kind(p)],
                                        ec=LOOP if p in loops else "#555555", lw=1.4 if p in loops else 0.7,
                                        zorder=2))
            ax.text(x, y, label(p), ha="center", va="center", zorder=3, family="monospace")
        notes = ["room/ : a folder of mitsonar", "name.py : a module of mitsonar's own folder",
                 "arrow : imports (at module level or inside a function)"]
        if loops:
            notes.append("red : a loop of packages (tests/test_package_graph.py KNOWN_LOOPS)")
        ax.text(0.1, -0.55, "      ".join(notes), ha="left", va="center", fontsize=8, color="#333333")
        out = io.StringIO() if fmt == "svg" else io.BytesIO()
        fig.savefig(out, format=fmt, metadata={"Date": None, "Creator": None} if fmt == "svg" else None)
        plt.close(fig)
    return out.getvalue()


def inline(svg: str) -> str:
    """The SVG as an element of the HTML page: no XML prolog, scaled to the page's width."""
    svg = svg[svg.index("<svg"):]
    head, rest = svg.split(">", 1)
    head = re.sub(r'\s(width|height)="[^"]*"', "", head)
    return f'{head} style="width:100%;height:auto" role="img" aria-label="import graph of the packages">{rest}'


class PackageGraphDirective(SphinxDirective):
    """``.. mitsonar-package-graph::``: the picture, drawn from the source at every build."""

    has_content = False

    def run(self):
        mods = pg.modules()
        for path in sorted(mods.values()):
            self.env.note_dependency(path)       # an import added anywhere redraws the page
        svg = draw(pg.package_graph())
        return [nodes.raw("", inline(svg), format="html")]


def setup(app):
    app.add_directive("mitsonar-package-graph", PackageGraphDirective)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
