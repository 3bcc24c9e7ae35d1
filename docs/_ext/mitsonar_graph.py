"""Sphinx directive ``.. mitsonar-package-graph::``: the import graph of mitsonar's packages, drawn
at build time from the source, as an SVG embedded in the page.

The graph and its drawing are ``scripts/package_graph.py``'s (`package_graph` over `import_graph`,
every import counted, those inside functions too; `draw`, `inline`): the one code the tests check.
"""
from __future__ import annotations

import os
import sys

from docutils import nodes
from sphinx.util.docutils import SphinxDirective

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.join(ROOT, "scripts"))

import package_graph as pg  # noqa: E402  (scripts/package_graph.py, the tests' graph)


class PackageGraphDirective(SphinxDirective):
    """``.. mitsonar-package-graph::``: the picture, drawn from the source at every build."""

    has_content = False

    def run(self):
        mods = pg.modules()
        for path in sorted(mods.values()):
            self.env.note_dependency(path)       # an import added anywhere redraws the page
        svg = pg.draw(pg.package_graph())
        return [nodes.raw("", pg.inline(svg), format="html")]


def setup(app):
    app.add_directive("mitsonar-package-graph", PackageGraphDirective)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
